#pragma once
/// \file
/// A headless EGL display + OpenGL ES 3 context (no window system): EGL_EXT_platform_device (a GPU through its
/// driver), else Mesa's surfaceless platform (llvmpipe on machines without a GPU), else the default display.

#include <memory>
#include <string>

namespace eyesim::render {

/// An off-screen GLES 3 context, current on the creating thread. Not copyable.
class EglContext {
public:
    /// Creates the context; on failure returns null and writes a one-line reason into `error`.
    static std::unique_ptr<EglContext> create(std::string& error);
    ~EglContext();
    EglContext(const EglContext&) = delete;
    EglContext& operator=(const EglContext&) = delete;

    /// Makes this context current on the calling thread (cheap when it already is). False on failure.
    bool make_current();
    /// GL_RENDERER, e.g. "llvmpipe (LLVM 15.0.6, 256 bits)" or the GPU's name.
    const std::string& renderer() const { return renderer_; }
    /// How the display was obtained: "device", "surfaceless" or "default".
    const std::string& platform() const { return platform_; }
    /// Whether an extension is in GL_EXTENSIONS.
    bool has_gl_extension(const char* name) const;

private:
    EglContext() = default;
    void* display_ = nullptr;
    void* context_ = nullptr;
    void* surface_ = nullptr;
    std::string renderer_, platform_, extensions_;
};

}  // namespace eyesim::render
