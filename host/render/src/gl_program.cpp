#include "gl_program.hpp"

namespace eyesim::render {
namespace {

GLuint compile(GLenum type, const char* src, const char* what, std::string& error) {
    GLuint s = glCreateShader(type);
    glShaderSource(s, 1, &src, nullptr);
    glCompileShader(s);
    GLint ok = 0;
    glGetShaderiv(s, GL_COMPILE_STATUS, &ok);
    if (!ok) {
        char log[1024] = {};
        glGetShaderInfoLog(s, sizeof(log), nullptr, log);
        error = std::string(what) + ": shader compile failed: " + log;
        glDeleteShader(s);
        return 0;
    }
    return s;
}

}  // namespace

GLuint link_program(const char* vertex_src, const char* fragment_src, const char* what, std::string& error) {
    const GLuint vs = compile(GL_VERTEX_SHADER, vertex_src, what, error);
    if (!vs) return 0;
    const GLuint fs = compile(GL_FRAGMENT_SHADER, fragment_src, what, error);
    if (!fs) {
        glDeleteShader(vs);
        return 0;
    }
    GLuint p = glCreateProgram();
    glAttachShader(p, vs);
    glAttachShader(p, fs);
    glLinkProgram(p);
    glDeleteShader(vs);
    glDeleteShader(fs);
    GLint ok = 0;
    glGetProgramiv(p, GL_LINK_STATUS, &ok);
    if (!ok) {
        char log[1024] = {};
        glGetProgramInfoLog(p, sizeof(log), nullptr, log);
        error = std::string(what) + ": program link failed: " + log;
        glDeleteProgram(p);
        return 0;
    }
    return p;
}

}  // namespace eyesim::render
