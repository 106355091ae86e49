# Shared target settings: warnings, sanitizers and the test/benchmark helpers every part uses.

# Project-code warnings (never applied to third-party headers: those come in as SYSTEM includes).
function(eyesim_defaults target)
  target_compile_options(${target} PRIVATE -Wall -Wextra -Wpedantic -Wshadow -Wnon-virtual-dtor
                                            -Wno-missing-field-initializers)
  if(EYESIM_WERROR)
    target_compile_options(${target} PRIVATE -Werror)
  endif()
  if(EYESIM_SANITIZE)
    # GCC 12 reports false maybe-uninitialized warnings inside libstdc++ (std::function, <regex>) once the
    # sanitizers change inlining; the release build keeps the warning.
    target_compile_options(${target} PRIVATE -fsanitize=address,undefined -fno-omit-frame-pointer
                                              -fno-sanitize-recover=undefined -Wno-maybe-uninitialized)
    target_link_options(${target} PRIVATE -fsanitize=address,undefined)
  endif()
endfunction()

# eyesim_library(NAME <target> DIR <part folder>) : static library from <dir>/src/*.cpp, headers in <dir>/include.
function(eyesim_library target)
  file(GLOB_RECURSE srcs CONFIGURE_DEPENDS "${CMAKE_CURRENT_SOURCE_DIR}/src/*.cpp")
  add_library(${target} STATIC ${srcs})
  target_include_directories(${target} PUBLIC "${CMAKE_CURRENT_SOURCE_DIR}/include")
  eyesim_defaults(${target})
endfunction()

# eyesim_test(<name> [SERIAL] [STRESS] SOURCES ... LIBS ...) : a Catch2 test program registered with CTest.
# Catch tags choose the CTest label: [stress] -> stress, [fuzz] -> fuzz, everything else -> unit.
# SERIAL: its tests never run beside others (they measure time).
# STRESS: the program has [stress] tests; only then are they looked for (a program without any would make the
# discovery warn that the [stress] selection contains no tests).
function(eyesim_test name)
  cmake_parse_arguments(T "SERIAL;STRESS" "" "SOURCES;LIBS" ${ARGN})
  set(serial "")
  if(T_SERIAL)
    set(serial RUN_SERIAL TRUE)
  endif()
  add_executable(${name} ${T_SOURCES})
  target_link_libraries(${name} PRIVATE eyesim_catch_main ${T_LIBS})
  target_compile_definitions(${name} PRIVATE EYESIM_SOURCE_DIR="${PROJECT_SOURCE_DIR}")
  eyesim_defaults(${name})
  catch_discover_tests(${name} TEST_SPEC "~[stress]~[fuzz]" TEST_PREFIX "${name}: "
                       PROPERTIES LABELS unit ${serial})
  # STRESS must match the sources: a [stress] tag in a test name's tag string ("...[stress]...").
  set(has_stress FALSE)
  foreach(src IN LISTS T_SOURCES)
    if(NOT IS_ABSOLUTE "${src}")
      set(src "${CMAKE_CURRENT_SOURCE_DIR}/${src}")
    endif()
    if(EXISTS "${src}")
      file(STRINGS "${src}" tagged REGEX "\"[^\"]*\\[stress\\][^\"]*\"")
      if(tagged)
        set(has_stress TRUE)
      endif()
    endif()
  endforeach()
  if(has_stress AND NOT T_STRESS)
    message(SEND_ERROR "eyesim_test(${name}): its sources have [stress] tests; add STRESS")
  elseif(T_STRESS AND NOT has_stress)
    message(SEND_ERROR "eyesim_test(${name}): STRESS given but no source has a [stress] test")
  endif()
  if(T_STRESS)
    catch_discover_tests(${name} TEST_SPEC "[stress]" TEST_PREFIX "${name}: "
                         PROPERTIES LABELS stress ${serial})
  endif()
endfunction()

# eyesim_bench(<name> SOURCES ... LIBS ...) : a benchmark program under bench/.
function(eyesim_bench name)
  cmake_parse_arguments(B "" "" "SOURCES;LIBS" ${ARGN})
  add_executable(${name} ${B_SOURCES})
  target_link_libraries(${name} PRIVATE ${B_LIBS})
  eyesim_defaults(${name})
endfunction()
