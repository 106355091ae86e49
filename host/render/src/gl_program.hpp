#pragma once
// Shader program building shared by the ZCOLL back-end and the scene renderer (GLES 3.0, current context).

#include <GLES3/gl3.h>

#include <string>

namespace eyesim::render {

/// Compiles and links a vertex + fragment shader pair. Returns 0 and a one-line reason in `error` (prefixed
/// with `what`) on failure; never leaks a shader or a program.
GLuint link_program(const char* vertex_src, const char* fragment_src, const char* what, std::string& error);

}  // namespace eyesim::render
