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

# eyesim_test(<name> [SERIAL] SOURCES ... LIBS ...) : a Catch2 test program registered with CTest.
# Catch tags choose the CTest label: [stress] -> stress, [fuzz] -> fuzz, everything else -> unit.
# SERIAL: its tests never run beside others (they measure time).
function(eyesim_test name)
  cmake_parse_arguments(T "SERIAL" "" "SOURCES;LIBS" ${ARGN})
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
  catch_discover_tests(${name} TEST_SPEC "[stress]" TEST_PREFIX "${name}: "
                       PROPERTIES LABELS stress ${serial})
endfunction()

# eyesim_bench(<name> SOURCES ... LIBS ...) : a benchmark program under bench/.
function(eyesim_bench name)
  cmake_parse_arguments(B "" "" "SOURCES;LIBS" ${ARGN})
  add_executable(${name} ${B_SOURCES})
  target_link_libraries(${name} PRIVATE ${B_LIBS})
  eyesim_defaults(${name})
endfunction()
