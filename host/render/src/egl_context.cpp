#include "eyesim/render/egl_context.hpp"

#include <EGL/egl.h>
#include <EGL/eglext.h>
#include <GLES3/gl3.h>

#include <cstring>

namespace eyesim::render {
namespace {

bool has_token(const char* list, const char* name) {
    if (list == nullptr) return false;
    const size_t n = std::strlen(name);
    for (const char* p = list; (p = std::strstr(p, name)) != nullptr; p += n)
        if ((p == list || p[-1] == ' ') && (p[n] == ' ' || p[n] == '\0')) return true;
    return false;
}

/// Tries the headless platforms in order of preference; returns an initialised display or EGL_NO_DISPLAY.
EGLDisplay open_display(std::string& platform, std::string& why) {
    const char* client_ext = eglQueryString(EGL_NO_DISPLAY, EGL_EXTENSIONS);
    auto get_platform_display =
        reinterpret_cast<PFNEGLGETPLATFORMDISPLAYEXTPROC>(eglGetProcAddress("eglGetPlatformDisplayEXT"));
    EGLint major = 0, minor = 0;
    if (get_platform_display && has_token(client_ext, "EGL_EXT_platform_device")) {
        auto query_devices = reinterpret_cast<PFNEGLQUERYDEVICESEXTPROC>(eglGetProcAddress("eglQueryDevicesEXT"));
        EGLDeviceEXT devices[8];
        EGLint count = 0;
        if (query_devices && query_devices(8, devices, &count) && count > 0) {
            // Prefer a hardware device (a software device advertises EGL_MESA_device_software).
            auto query_string =
                reinterpret_cast<PFNEGLQUERYDEVICESTRINGEXTPROC>(eglGetProcAddress("eglQueryDeviceStringEXT"));
            for (EGLint i = 0; i < count; ++i) {
                const char* dev_ext = query_string ? query_string(devices[i], EGL_EXTENSIONS) : nullptr;
                if (has_token(dev_ext, "EGL_MESA_device_software")) continue;
                EGLDisplay d = get_platform_display(EGL_PLATFORM_DEVICE_EXT, devices[i], nullptr);
                if (d != EGL_NO_DISPLAY && eglInitialize(d, &major, &minor)) {
                    platform = "device";
                    return d;
                }
            }
        }
    }
    if (get_platform_display && has_token(client_ext, "EGL_MESA_platform_surfaceless")) {
        EGLDisplay d = get_platform_display(EGL_PLATFORM_SURFACELESS_MESA, EGL_DEFAULT_DISPLAY, nullptr);
        if (d != EGL_NO_DISPLAY && eglInitialize(d, &major, &minor)) {
            platform = "surfaceless";
            return d;
        }
    }
    EGLDisplay d = eglGetDisplay(EGL_DEFAULT_DISPLAY);
    if (d != EGL_NO_DISPLAY && eglInitialize(d, &major, &minor)) {
        platform = "default";
        return d;
    }
    why = client_ext ? "no EGL display could be initialised (tried device, surfaceless, default)"
                     : "EGL client extensions unavailable and no default display";
    return EGL_NO_DISPLAY;
}

}  // namespace

std::unique_ptr<EglContext> EglContext::create(std::string& error) {
    std::unique_ptr<EglContext> c(new EglContext());
    std::string why;
    EGLDisplay d = open_display(c->platform_, why);
    if (d == EGL_NO_DISPLAY) {
        error = "EGL: " + why;
        return nullptr;
    }
    c->display_ = d;
    if (!eglBindAPI(EGL_OPENGL_ES_API)) {
        error = "EGL: eglBindAPI(EGL_OPENGL_ES_API) failed";
        return nullptr;
    }
    const bool surfaceless = has_token(eglQueryString(d, EGL_EXTENSIONS), "EGL_KHR_surfaceless_context");
    const EGLint cfg_attr[] = {EGL_RENDERABLE_TYPE, EGL_OPENGL_ES3_BIT, EGL_SURFACE_TYPE,
                               surfaceless ? 0 : EGL_PBUFFER_BIT, EGL_NONE};
    EGLConfig cfg = nullptr;
    EGLint n = 0;
    if (!eglChooseConfig(d, cfg_attr, &cfg, 1, &n) || n < 1) {
        error = "EGL: no config with EGL_OPENGL_ES3_BIT (platform " + c->platform_ + ")";
        return nullptr;
    }
    const EGLint ctx_attr[] = {EGL_CONTEXT_MAJOR_VERSION, 3, EGL_CONTEXT_MINOR_VERSION, 0, EGL_NONE};
    EGLContext ctx = eglCreateContext(d, cfg, EGL_NO_CONTEXT, ctx_attr);
    if (ctx == EGL_NO_CONTEXT) {
        error = "EGL: eglCreateContext for OpenGL ES 3.0 failed (platform " + c->platform_ + ")";
        return nullptr;
    }
    c->context_ = ctx;
    if (!surfaceless) {
        const EGLint pb_attr[] = {EGL_WIDTH, 1, EGL_HEIGHT, 1, EGL_NONE};
        EGLSurface s = eglCreatePbufferSurface(d, cfg, pb_attr);
        if (s == EGL_NO_SURFACE) {
            error = "EGL: neither surfaceless contexts nor a pbuffer surface are available";
            return nullptr;
        }
        c->surface_ = s;
    }
    if (!c->make_current()) {
        error = "EGL: eglMakeCurrent failed";
        return nullptr;
    }
    const char* r = reinterpret_cast<const char*>(glGetString(GL_RENDERER));
    const char* e = reinterpret_cast<const char*>(glGetString(GL_EXTENSIONS));
    c->renderer_ = r ? r : "unknown";
    c->extensions_ = e ? e : "";
    return c;
}

EglContext::~EglContext() {
    if (display_ == nullptr) return;
    EGLDisplay d = static_cast<EGLDisplay>(display_);
    eglMakeCurrent(d, EGL_NO_SURFACE, EGL_NO_SURFACE, EGL_NO_CONTEXT);
    if (surface_) eglDestroySurface(d, static_cast<EGLSurface>(surface_));
    if (context_) eglDestroyContext(d, static_cast<EGLContext>(context_));
    // The display is left initialised: other contexts of this process may share it (eglTerminate would
    // invalidate them).
}

bool EglContext::make_current() {
    if (eglGetCurrentContext() == static_cast<EGLContext>(context_)) return true;
    EGLSurface s = surface_ ? static_cast<EGLSurface>(surface_) : EGL_NO_SURFACE;
    return eglMakeCurrent(static_cast<EGLDisplay>(display_), s, s, static_cast<EGLContext>(context_)) == EGL_TRUE;
}

bool EglContext::has_gl_extension(const char* name) const { return has_token(extensions_.c_str(), name); }

}  // namespace eyesim::render
