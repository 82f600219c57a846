/* vrcorrect's OpenXR API layer: a thin C shim around vrcorrect.runtime.layer.engine (Python).
 *
 * Loaded by the OpenXR loader from a layer manifest (implicit: `vrcorrect layer install`;
 * explicit for tests: XR_API_LAYER_PATH + XR_ENABLE_API_LAYERS). For OpenGL sessions
 * (XR_KHR_opengl_enable, Xlib/GLX binding) and Vulkan sessions (XR_KHR_vulkan_enable,
 * XR_KHR_vulkan_enable2: vrcorrect_vulkan.c) it gives every application swapchain of a supported
 * format a layer-owned output swapchain of the same format and size. At xrEndFrame, for every view
 * of every projection layer, the Python engine corrects the application's last released image over
 * the submitted imageRect into the output swapchain, and the frame goes down the chain with a copy
 * of the frame description that names the output swapchains. The application's structures and
 * images are never written.
 *
 * OpenGL: the engine runs on the application's GL context (current at xrEndFrame); the GL state the
 * correction touches is saved before and restored after. Formats: GL_RGBA16F, GL_RGB10_A2,
 * GL_SRGB8_ALPHA8, GL_RGBA8.
 * Vulkan: the engine runs on a GL context of its own (headless EGL); the submitted rects are copied
 * on the application's queue into images of the layer's whose memory GL imports, and the corrected
 * result is copied back into the output images (vrcorrect_vulkan.c). Formats: R16G16B16A16_SFLOAT,
 * A2B10G10R10_UNORM_PACK32, R8G8B8A8_SRGB/UNORM, B8G8R8A8_SRGB/UNORM.
 *
 * Anything the layer cannot do passes the frame through unchanged and logs one line naming the
 * reason (a Direct3D or OpenGL ES session, a format outside the lists, a Vulkan device without
 * external memory, no Python, an engine failure, a GL error, ...).
 *
 * Nothing holds xrEndFrame up while a prescription (re)loads: the engine builds the eye models on a
 * worker thread and passes frames through (first load) or keeps the current correction (reload)
 * meanwhile; the shim releases the GIL between its calls so that the worker runs.
 *
 * Python: when the process has none running, the shim starts one (libpython is linked; the
 * prefix and sys.path entries come from vrcorrect_layer.cfg beside the library, written by
 * `vrcorrect layer install`); when it has (a pyopenxr application), it takes the GIL with
 * PyGILState_Ensure. Python is never finalised by the layer.
 *
 * Environment: DISABLE_VRCORRECT_LAYER (the manifest's disable_environment: the loader skips the
 * layer), VRCORRECT_LAYER_LOG (log file), VRCORRECT_LAYER_FORMATS (comma-separated hex swapchain
 * formats the layer corrects, a subset of the lists above; default all); the engine reads the
 * others (vrcorrect/runtime/layer/engine.py).
 *
 * Limits: one session per instance is corrected; a projection view must use imageArrayIndex 0 of a
 * 2D, single-sample, single-mip swapchain; views beyond two and other composition layers pass
 * through.
 *
 * The loader negotiation structures are declared here from the OpenXR loader specification
 * ("OpenXR Loader - Design and Operation", API layer interface version 1), which the Khronos headers
 * (Debian libopenxr-dev 1.0.20) do not declare; every other type comes from the Khronos headers
 * (libopenxr-dev, libvulkan-dev, libgl-dev, libx11-dev).
 */
#include "vrcorrect_layer.h"

#include <dlfcn.h>
#include <stdarg.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <sys/stat.h>
#include <pthread.h>

#define LAYER_NAME "XR_APILAYER_VRCORRECT_correction"
#define HELD_MS 100.0              /* a passed-through frame the layer held longer than this is logged */
#define EXPORT __attribute__((visibility("default")))

/* ------------------------------------------------------------------ loader negotiation (spec) */
enum {
    LOADER_STRUCT_LOADER_INFO = 1, LOADER_STRUCT_API_LAYER_REQUEST = 2,
    LOADER_STRUCT_API_LAYER_CREATE_INFO = 4, LOADER_STRUCT_API_LAYER_NEXT_INFO = 5,
};
#define MAX_API_LAYER_NAME_SIZE 256
#define API_LAYER_MAX_SETTINGS_PATH_SIZE 512

typedef struct {
    int32_t structType; uint32_t structVersion; size_t structSize;
    uint32_t minInterfaceVersion, maxInterfaceVersion;
    XrVersion minApiVersion, maxApiVersion;
} LayerNegotiateLoaderInfo;

struct LayerApiLayerNextInfo;
typedef struct {
    int32_t structType; uint32_t structVersion; size_t structSize;
    void *loaderInstance;
    char settings_file_location[API_LAYER_MAX_SETTINGS_PATH_SIZE];
    struct LayerApiLayerNextInfo *nextInfo;
} LayerApiLayerCreateInfo;

typedef XrResult (XRAPI_PTR *PFN_createApiLayerInstance)(const XrInstanceCreateInfo *, const LayerApiLayerCreateInfo *,
                                                         XrInstance *);
typedef struct LayerApiLayerNextInfo {
    int32_t structType; uint32_t structVersion; size_t structSize;
    char layerName[MAX_API_LAYER_NAME_SIZE];
    PFN_xrGetInstanceProcAddr nextGetInstanceProcAddr;
    PFN_createApiLayerInstance nextCreateApiLayerInstance;
    struct LayerApiLayerNextInfo *next;
} LayerApiLayerNextInfo;

typedef struct {
    int32_t structType; uint32_t structVersion; size_t structSize;
    uint32_t layerInterfaceVersion; XrVersion layerApiVersion;
    PFN_xrGetInstanceProcAddr getInstanceProcAddr;
    PFN_createApiLayerInstance createApiLayerInstance;
} LayerNegotiateApiLayerRequest;

/* ------------------------------------------------------------------ GL through glXGetProcAddress */
#define L_GL_SRGB8_ALPHA8 0x8C43
#define L_GL_RGBA8 0x8058
#define L_GL_RGB10_A2 0x8059
#define L_GL_RGBA16F 0x881A

/* The one GL entry point the shim itself calls: the engine corrects on contexts of its own (which share
 * the application's textures) and never touches the application's GL state. */
static struct {
    GLXContext (*GetCurrentContext)(void);
} gl;

static int load_gl(void) {
    if (gl.GetCurrentContext) return 1;
    void *lib = dlopen("libGL.so.1", RTLD_NOW | RTLD_GLOBAL);
    if (!lib) return 0;
    void *(*gpa)(const char *) = (void *(*)(const char *))dlsym(lib, "glXGetProcAddressARB");
    if (!gpa) return 0;
    *(void **)&gl.GetCurrentContext = gpa("glXGetCurrentContext");
    return gl.GetCurrentContext != NULL;
}

/* ------------------------------------------------------------------ logging (one line a reason) */
static pthread_mutex_t lock = PTHREAD_MUTEX_INITIALIZER;
static char log_path[1024];
LayerState L;

static void resolve_log_path(void) {
    const char *env = getenv("VRCORRECT_LAYER_LOG");
    if (env && *env) { snprintf(log_path, sizeof log_path, "%s", env); return; }
    const char *state = getenv("XDG_STATE_HOME"), *home = getenv("HOME");
    if (state && *state) snprintf(log_path, sizeof log_path, "%s/vrcorrect/layer.log", state);
    else if (home && *home) snprintf(log_path, sizeof log_path, "%s/.local/state/vrcorrect/layer.log", home);
    else log_path[0] = 0;
}

void layer_log(const char *fmt, ...) {
    char line[1024];
    va_list ap;
    va_start(ap, fmt);
    vsnprintf(line, sizeof line, fmt, ap);
    va_end(ap);
    fprintf(stderr, "vrcorrect layer: %s\n", line);
    if (!log_path[0]) resolve_log_path();
    if (!log_path[0]) return;
    char dir[1024];
    snprintf(dir, sizeof dir, "%s", log_path);
    for (char *p = dir + 1; *p; p++)
        if (*p == '/') { *p = 0; mkdir(dir, 0755); *p = '/'; }
    FILE *f = fopen(log_path, "a");
    if (!f) return;
    time_t now = time(NULL);
    struct tm tm;
    gmtime_r(&now, &tm);
    char stamp[32];
    strftime(stamp, sizeof stamp, "%Y-%m-%dT%H:%M:%SZ", &tm);
    fprintf(f, "%s %s\n", stamp, line);
    fclose(f);
}

/* Log a pass-through reason once (until a different reason or a corrected frame comes). */
void pass_reason(const char *reason) {
    if (strcmp(reason, L.last_reason) == 0) return;
    snprintf(L.last_reason, sizeof L.last_reason, "%s", reason);
    layer_log("pass-through: %s", reason);
}

Chain *chain_of(XrSwapchain h) {
    for (int i = 0; i < MAX_SWAPCHAINS; i++)
        if (L.chains[i].app == h && h != XR_NULL_HANDLE) return &L.chains[i];
    return NULL;
}

double now_ms(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return 1e3 * (double)ts.tv_sec + 1e-6 * (double)ts.tv_nsec;
}

/* VRCORRECT_LAYER_FORMATS: a comma-separated list of hex formats the layer may correct (a way to
 * restrict it, e.g. to sRGB swapchains only); unset or empty: every format of the lists. */
int format_allowed(int64_t format) {
    const char *list = getenv("VRCORRECT_LAYER_FORMATS");
    if (!list || !*list) return 1;
    for (const char *p = list; *p;) {
        char *end;
        long long v = strtoll(p, &end, 16);
        if (end == p) break;
        if (v == format) return 1;
        p = end;
        while (*p == ',' || *p == ' ') p++;
    }
    return 0;
}

/* ------------------------------------------------------------------ embedded Python */
static void self_dir(char *out, size_t size) {
    Dl_info info;
    out[0] = 0;
    if (dladdr((void *)self_dir, &info) && info.dli_fname) {
        snprintf(out, size, "%s", info.dli_fname);
        char *slash = strrchr(out, '/');
        if (slash) *slash = 0; else out[0] = 0;
    }
}

/* vrcorrect_layer.cfg: "home=<python prefix>" and "path=<sys.path entry>" lines, written by
 * `vrcorrect layer install`: beside the library (a layer the install's fallback or a test built), else
 * in $XDG_DATA_HOME/vrcorrect/layer/ (default ~/.local/share; the library built into the package lies
 * in site-packages, where install writes nothing). */
static FILE *open_cfg(void) {
    char dir[1024], file[1200];
    self_dir(dir, sizeof dir);
    snprintf(file, sizeof file, "%s/vrcorrect_layer.cfg", dir);
    FILE *f = fopen(file, "r");
    if (f) return f;
    const char *data = getenv("XDG_DATA_HOME"), *home = getenv("HOME");
    if (data && data[0]) snprintf(file, sizeof file, "%s/vrcorrect/layer/vrcorrect_layer.cfg", data);
    else if (home && home[0]) snprintf(file, sizeof file, "%s/.local/share/vrcorrect/layer/vrcorrect_layer.cfg", home);
    else return NULL;
    return fopen(file, "r");
}

static int read_cfg(char home[1024], char paths[16][1024], int *npaths) {
    FILE *f = open_cfg();
    *npaths = 0;
    home[0] = 0;
    if (!f) return 0;
    char line[1000];
    while (fgets(line, sizeof line, f)) {
        line[strcspn(line, "\r\n")] = 0;
        if (strncmp(line, "home=", 5) == 0) snprintf(home, 1024, "%s", line + 5);
        else if (strncmp(line, "path=", 5) == 0 && *npaths < 16) snprintf(paths[(*npaths)++], 1024, "%s", line + 5);
    }
    fclose(f);
    return 1;
}

static int python_start(void) {
    if (L.python_failed) return 0;
    char home[1024], paths[16][1024];
    int npaths = 0;
    read_cfg(home, paths, &npaths);
    if (!Py_IsInitialized()) {
        /* The loader opens layers with RTLD_LOCAL: make libpython's symbols global, or Python's own
         * extension modules (lib-dynload) cannot resolve them. */
        Dl_info pyinfo;
        if (dladdr((void *)Py_IsInitialized, &pyinfo) && pyinfo.dli_fname)
            dlopen(pyinfo.dli_fname, RTLD_NOW | RTLD_GLOBAL | RTLD_NOLOAD);
        PyConfig config;
        PyConfig_InitIsolatedConfig(&config);
        config.install_signal_handlers = 0;
        config.site_import = 1;
        PyStatus status = PyStatus_Ok();
        if (home[0]) status = PyConfig_SetBytesString(&config, &config.home, home);
        if (!PyStatus_Exception(status)) status = Py_InitializeFromConfig(&config);
        PyConfig_Clear(&config);
        if (PyStatus_Exception(status)) {
            L.python_failed = 1;
            layer_log("pass-through: Python could not start in this process (%s)",
                      status.err_msg ? status.err_msg : "unknown");
            return 0;
        }
        L.we_initialised = 1;
        PyEval_SaveThread();       /* the GIL is taken per call with PyGILState_Ensure */
    }
    PyGILState_STATE g = PyGILState_Ensure();
    PyObject *sys_path = PySys_GetObject("path");  /* borrowed */
    for (int i = npaths - 1; sys_path && i >= 0; i--) {
        PyObject *p = PyUnicode_DecodeFSDefault(paths[i]);
        if (p && PySequence_Contains(sys_path, p) == 0) PyList_Insert(sys_path, 0, p);
        Py_XDECREF(p);
    }
    /* the .pth files there too (a venv's editable installs, or one that reaches its dependencies through a
     * .pth), as the venv's own interpreter processes them: site.addsitedir on a folder already in sys.path
     * keeps its place and adds what its .pth files name */
    PyObject *site = PyImport_ImportModule("site");
    for (int i = 0; site && i < npaths; i++) {
        PyObject *p = PyUnicode_DecodeFSDefault(paths[i]);
        PyObject *r = p ? PyObject_CallMethod(site, "addsitedir", "O", p) : NULL;
        Py_XDECREF(r);
        Py_XDECREF(p);
    }
    Py_XDECREF(site);
    PyErr_Clear();
    PyGILState_Release(g);
    return 1;
}

static void python_error(const char *what) {
    PyObject *type, *value, *tb;
    PyErr_Fetch(&type, &value, &tb);
    PyObject *s = value ? PyObject_Str(value) : NULL;
    const char *text = s ? PyUnicode_AsUTF8(s) : NULL;
    layer_log("pass-through: %s: %s%s%s", what, type ? ((PyTypeObject *)type)->tp_name : "error",
              text ? ": " : "", text ? text : "");
    Py_XDECREF(s);
    Py_XDECREF(type);
    Py_XDECREF(value);
    Py_XDECREF(tb);
    PyErr_Clear();
}

/* Calls a method of the engine; returns its result as a new reference, or NULL (logged). */
PyObject *engine_call(const char *method, const char *format, ...) {
    if (!L.engine) return NULL;
    va_list ap;
    va_start(ap, format);
    PyObject *args = Py_VaBuildValue(format, ap);
    va_end(ap);
    PyObject *fn = args ? PyObject_GetAttrString(L.engine, method) : NULL;
    PyObject *result = fn ? PyObject_CallObject(fn, args) : NULL;
    Py_XDECREF(fn);
    Py_XDECREF(args);
    if (!result) {
        char what[128];
        snprintf(what, sizeof what, "the correction engine failed in %s", method);
        python_error(what);
    }
    return result;
}

static void engine_start(uint32_t view_w, uint32_t view_h, const char *vendor) {
    if (L.engine || L.engine_failed || !python_start()) return;
    PyGILState_STATE g = PyGILState_Ensure();
    PyObject *module = PyImport_ImportModule("vrcorrect.runtime.layer.engine");
    if (!module) {
        python_error("cannot import vrcorrect.runtime.layer.engine");
        L.engine_failed = 1;
    } else {
        PyObject *cls = PyObject_GetAttrString(module, "Engine");
        L.engine = cls ? PyObject_CallFunction(cls, "(IIs)", view_w, view_h, vendor) : NULL;
        Py_XDECREF(cls);
        Py_DECREF(module);
        if (!L.engine) {
            python_error("cannot start the correction engine");
            L.engine_failed = 1;
        }
    }
    PyGILState_Release(g);
}

static void engine_stop(void) {
    if (!L.engine) return;
    PyGILState_STATE g = PyGILState_Ensure();
    PyObject *r = engine_call("close", "()");
    Py_XDECREF(r);
    Py_CLEAR(L.engine);
    PyGILState_Release(g);
}

/* ------------------------------------------------------------------ intercepted calls */
static XrResult XRAPI_CALL layer_GetInstanceProcAddr(XrInstance, const char *, PFN_xrVoidFunction *);

static XrResult XRAPI_CALL layer_DestroyInstance(XrInstance instance) {
    engine_stop();
    vk_forget_instance();
    XrResult r = L.DestroyInstance(instance);
    L.instance = XR_NULL_HANDLE;
    return r;
}

/* Sessions the layer does not correct, named for the log line. */
static const char *binding_name(XrStructureType t) {
    switch ((int)t) {
    case 1000027000: return "Direct3D 11 (XR_KHR_D3D11_enable)";
    case 1000028000: return "Direct3D 12 (XR_KHR_D3D12_enable)";
    case 1000024001: return "OpenGL ES (XR_KHR_opengl_es_enable)";
    case 1000023002: return "OpenGL on XCB (XR_KHR_opengl_enable, XCB binding)";
    case 1000023003: return "OpenGL on Wayland (XR_KHR_opengl_enable, Wayland binding)";
    case 1000048004: return "OpenGL through EGL (XR_MNDX_egl_enable)";
    default: return NULL;
    }
}

/* The runtime's recommended view size (0 x 0 when it does not say). */
static void view_size(XrInstance instance, XrSystemId system, uint32_t *w, uint32_t *h) {
    uint32_t n = 0;
    XrViewConfigurationView views[MAX_VIEWS];
    for (uint32_t i = 0; i < MAX_VIEWS; i++) views[i] = (XrViewConfigurationView){.type = XR_TYPE_VIEW_CONFIGURATION_VIEW};
    *w = *h = 0;
    if (L.EnumerateViewConfigurationViews &&
        XR_SUCCEEDED(L.EnumerateViewConfigurationViews(instance, system, XR_VIEW_CONFIGURATION_TYPE_PRIMARY_STEREO,
                                                       MAX_VIEWS, &n, views)) && n > 0) {
        *w = views[0].recommendedImageRectWidth;
        *h = views[0].recommendedImageRectHeight;
    }
}

static XrResult XRAPI_CALL layer_CreateSession(XrInstance instance, const XrSessionCreateInfo *info, XrSession *session) {
    const XrGraphicsBindingOpenGLXlibKHR *glx = NULL;
    const XrGraphicsBindingVulkanKHR *vulkan = NULL;
    const char *other = NULL;
    for (const XrBaseInStructure *b = info ? (const XrBaseInStructure *)info->next : NULL; b; b = b->next) {
        if (b->type == XR_TYPE_GRAPHICS_BINDING_OPENGL_XLIB_KHR) glx = (const XrGraphicsBindingOpenGLXlibKHR *)b;
        else if (b->type == XR_TYPE_GRAPHICS_BINDING_VULKAN_KHR) vulkan = (const XrGraphicsBindingVulkanKHR *)b;
        else if (binding_name(b->type)) other = binding_name(b->type);
    }
    L.last_reason[0] = 0;
    if (!glx && !vulkan) {     /* decided from the application's request: the session passes through whatever the runtime says */
        char reason[256];
        snprintf(reason, sizeof reason, "the application renders with %s; vrcorrect corrects OpenGL (Xlib/GLX) and "
                 "Vulkan sessions", other ? other : "a graphics API it does not name");
        pass_reason(reason);
        return L.CreateSession(instance, info, session);
    }
    XrResult r = L.CreateSession(instance, info, session);
    if (XR_FAILED(r)) return r;
    if (L.session != XR_NULL_HANDLE) {
        pass_reason("a second session at once: only the first is corrected");
        return r;
    }
    if (!L.EnumerateSwapchainImages || !L.AcquireSwapchainImage || !L.WaitSwapchainImage ||
        !L.ReleaseSwapchainImage || !L.DestroySwapchain || !L.EndFrame) {
        pass_reason("the next layer or runtime lacks a swapchain or frame function");
        return r;
    }
    if (glx) {
        if (!load_gl()) {
            pass_reason("libGL.so.1 or a GL entry point could not be loaded");
            return r;
        }
        L.context = glx->glxContext;
        L.api = API_GL;
    } else {
        char reason[256] = "";
        if (!vk_session_start(vulkan, reason, sizeof reason)) {
            vk_session_stop();
            pass_reason(reason);
            return r;
        }
        L.api = API_VULKAN;
    }
    L.session = *session;
    uint32_t w, h;
    view_size(instance, info->systemId, &w, &h);
    engine_start(w, h, L.api == API_GL ? "OpenGL" : "Vulkan");
    if (L.api == API_VULKAN && L.engine) vk_session_semaphores();
    if (glx && L.engine) {        /* the engine's contexts share the application's textures through its binding */
        PyGILState_STATE g = PyGILState_Ensure();
        PyObject *res = engine_call("attach_glx", "(KKK)", (unsigned long long)(uintptr_t)glx->xDisplay,
                                    (unsigned long long)(uintptr_t)glx->glxFBConfig,
                                    (unsigned long long)(uintptr_t)glx->glxContext);
        Py_XDECREF(res);
        PyGILState_Release(g);
    }
    return r;
}

static void release_engine_gl(void) {
    if (!L.engine) return;
    int current = 1;                 /* the engine's objects live on contexts of its own: always released */
    PyGILState_STATE g = PyGILState_Ensure();
    PyObject *res = engine_call("release_gl", "(i)", current);
    Py_XDECREF(res);
    PyGILState_Release(g);
}

/* OpenGL: the engine lets go of what it made for a swapchain's textures (wrappers, framebuffers on its
 * own context), whose names the runtime may give to new textures. */
static void forget_gl_textures(Chain *c) {
    if (!L.engine || c->out == XR_NULL_HANDLE) return;
    int current = 1;
    PyGILState_STATE g = PyGILState_Ensure();
    PyObject *names = PyList_New(0);
    for (uint32_t i = 0; names && i < c->app_count + c->out_count; i++) {
        PyObject *n = PyLong_FromUnsignedLong(i < c->app_count ? c->app_tex[i] : c->out_tex[i - c->app_count]);
        if (n) PyList_Append(names, n);
        Py_XDECREF(n);
    }
    PyObject *res = names ? engine_call("forget_textures", "(Oi)", names, current) : NULL;
    Py_XDECREF(res);
    Py_XDECREF(names);
    PyErr_Clear();
    PyGILState_Release(g);
}

static void forget_chain(Chain *c) {
    int id = (int)(c - L.chains);
    if (L.api == API_VULKAN) vk_chain_stop(c, id);
    if (L.api == API_GL) forget_gl_textures(c);
    if (c->out != XR_NULL_HANDLE) L.DestroySwapchain(c->out);
    memset(c, 0, sizeof *c);
}

static XrResult XRAPI_CALL layer_DestroySession(XrSession session) {
    gaze_session_end(session);
    if (session == L.session) {
        for (int i = 0; i < MAX_SWAPCHAINS; i++)   /* the application should have destroyed its swapchains */
            if (L.chains[i].app != XR_NULL_HANDLE && L.chains[i].session == session) forget_chain(&L.chains[i]);
        release_engine_gl();
        if (L.api == API_VULKAN) vk_session_stop();
        L.session = XR_NULL_HANDLE;
        L.api = API_NONE;
    }
    return L.DestroySession(session);
}

static int enumerate_images(XrSwapchain h, GLuint *tex, VkImage *images, uint32_t *count) {
    XrSwapchainImageOpenGLKHR gl_images[MAX_IMAGES];
    XrSwapchainImageVulkanKHR vk_images[MAX_IMAGES];
    uint32_t n = 0;
    if (XR_FAILED(L.EnumerateSwapchainImages(h, 0, &n, NULL)) || n == 0 || n > MAX_IMAGES) return 0;
    for (uint32_t i = 0; i < n; i++) {
        gl_images[i] = (XrSwapchainImageOpenGLKHR){.type = XR_TYPE_SWAPCHAIN_IMAGE_OPENGL_KHR};
        vk_images[i] = (XrSwapchainImageVulkanKHR){.type = XR_TYPE_SWAPCHAIN_IMAGE_VULKAN_KHR};
    }
    XrSwapchainImageBaseHeader *list = L.api == API_GL ? (XrSwapchainImageBaseHeader *)gl_images
                                                       : (XrSwapchainImageBaseHeader *)vk_images;
    if (XR_FAILED(L.EnumerateSwapchainImages(h, n, &n, list))) return 0;
    for (uint32_t i = 0; i < n; i++) {
        if (L.api == API_GL) tex[i] = gl_images[i].image;
        else images[i] = vk_images[i].image;
    }
    *count = n;
    return 1;
}

static const char *gl_format_name(int64_t format) {
    switch (format) {
    case L_GL_RGBA16F: return "GL_RGBA16F";
    case L_GL_RGB10_A2: return "GL_RGB10_A2";
    case L_GL_SRGB8_ALPHA8: return "GL_SRGB8_ALPHA8";
    case L_GL_RGBA8: return "GL_RGBA8";
    default: return NULL;
    }
}

static XrResult XRAPI_CALL layer_CreateSwapchain(XrSession session, const XrSwapchainCreateInfo *info,
                                                 XrSwapchain *swapchain) {
    if (session != L.session || L.api == API_NONE || !info) return L.CreateSwapchain(session, info, swapchain);
    int api = L.api;
    const char *name = api == API_GL ? gl_format_name(info->format) : vk_format_name(info->format);
    char reason[256] = "";
    if (!name)
        snprintf(reason, sizeof reason, "swapchain format 0x%llX is not supported (%s are)", (unsigned long long)info->format,
                 api == API_GL ? "GL_RGBA16F 0x881A, GL_RGB10_A2 0x8059, GL_SRGB8_ALPHA8 0x8C43, GL_RGBA8 0x8058"
                               : "R16G16B16A16_SFLOAT 0x61, A2B10G10R10_UNORM_PACK32 0x40, R8G8B8A8_SRGB 0x2B, "
                                 "B8G8R8A8_SRGB 0x32, R8G8B8A8_UNORM 0x25, B8G8R8A8_UNORM 0x2C");
    else if (!format_allowed(info->format))
        snprintf(reason, sizeof reason, "swapchain format %s 0x%llX is left out by VRCORRECT_LAYER_FORMATS", name,
                 (unsigned long long)info->format);
    else if (info->arraySize != 1 || info->faceCount != 1 || info->sampleCount != 1 || info->mipCount != 1)
        snprintf(reason, sizeof reason, "a swapchain with arraySize %u, faceCount %u, sampleCount %u, mipCount %u "
                 "(only 1, 1, 1, 1 is corrected)", info->arraySize, info->faceCount, info->sampleCount, info->mipCount);
    else if (!(info->usageFlags & XR_SWAPCHAIN_USAGE_COLOR_ATTACHMENT_BIT))
        snprintf(reason, sizeof reason, "a swapchain without COLOR_ATTACHMENT usage (a depth buffer?) is not corrected");
    /* Vulkan: the layer copies the submitted rects out of the application's images, which needs their
     * TRANSFER_SRC usage; the application's own structure is left as it is */
    XrSwapchainCreateInfo app = *info;
    if (!reason[0] && api == API_VULKAN) app.usageFlags |= XR_SWAPCHAIN_USAGE_TRANSFER_SRC_BIT;
    XrResult r = L.CreateSwapchain(session, &app, swapchain);
    if (XR_FAILED(r)) return r;
    if (reason[0]) {
        if (info->usageFlags & XR_SWAPCHAIN_USAGE_COLOR_ATTACHMENT_BIT) pass_reason(reason);
        return r;
    }
    Chain *c = NULL;
    for (int i = 0; i < MAX_SWAPCHAINS && !c; i++)
        if (L.chains[i].app == XR_NULL_HANDLE) c = &L.chains[i];
    if (!c) {
        pass_reason("more swapchains than the layer tracks (32): the newest is passed through");
        return r;
    }
    memset(c, 0, sizeof *c);
    c->app = *swapchain;
    c->session = session;
    c->format = info->format;
    c->width = info->width;
    c->height = info->height;
    c->released = -1;
    if (!enumerate_images(c->app, c->app_tex, c->app_image, &c->app_count)) {
        pass_reason("could not list the application's swapchain images");
        return r;
    }
    XrSwapchainCreateInfo out = *info;
    out.next = NULL;
    out.createFlags = 0;
    out.usageFlags = XR_SWAPCHAIN_USAGE_COLOR_ATTACHMENT_BIT | XR_SWAPCHAIN_USAGE_SAMPLED_BIT |
                     (api == API_VULKAN ? XR_SWAPCHAIN_USAGE_TRANSFER_DST_BIT : 0);
    XrSwapchain h = XR_NULL_HANDLE;
    XrResult ro = L.CreateSwapchain(session, &out, &h);
    if (XR_FAILED(ro)) {
        snprintf(reason, sizeof reason, "the runtime refused the layer's output swapchain (XrResult %d)", ro);
        pass_reason(reason);
        return r;
    }
    c->out = h;
    int failed = 0;
    if (!enumerate_images(h, c->out_tex, c->out_image, &c->out_count)) {
        snprintf(reason, sizeof reason, "could not list the output swapchain's images");
        failed = 1;
    } else if (api == API_VULKAN) {
        failed = !vk_chain_start(c, (int)(c - L.chains), reason, sizeof reason);   /* reason "": the engine logged */
    } else if (L.engine) {        /* OpenGL: the engine prepares its corrections for this format and size */
        PyGILState_STATE g = PyGILState_Ensure();
        PyObject *res = engine_call("add_swapchain", "(iLII)", (int)(c - L.chains), (long long)c->format, c->width,
                                    c->height);
        failed = !res || !PyObject_IsTrue(res);      /* the engine logged why */
        Py_XDECREF(res);
        PyGILState_Release(g);
    }
    if (failed) {
        if (api == API_VULKAN) vk_chain_stop(c, (int)(c - L.chains));
        L.DestroySwapchain(h);
        c->out = XR_NULL_HANDLE;
        if (reason[0]) pass_reason(reason);
    }
    return r;
}

static XrResult XRAPI_CALL layer_DestroySwapchain(XrSwapchain swapchain) {
    Chain *c = chain_of(swapchain);
    if (c) forget_chain(c);
    return L.DestroySwapchain(swapchain);
}

static XrResult XRAPI_CALL layer_AcquireSwapchainImage(XrSwapchain swapchain, const XrSwapchainImageAcquireInfo *info,
                                                       uint32_t *index) {
    XrResult r = L.AcquireSwapchainImage(swapchain, info, index);
    Chain *c = chain_of(swapchain);
    if (XR_SUCCEEDED(r) && c && c->nacquired < MAX_IMAGES) c->acquired[c->nacquired++] = *index;
    return r;
}

static XrResult XRAPI_CALL layer_ReleaseSwapchainImage(XrSwapchain swapchain, const XrSwapchainImageReleaseInfo *info) {
    XrResult r = L.ReleaseSwapchainImage(swapchain, info);
    Chain *c = chain_of(swapchain);
    if (XR_SUCCEEDED(r) && c && c->nacquired > 0) {
        c->released = (int)c->acquired[0];
        memmove(c->acquired, c->acquired + 1, sizeof(uint32_t) * (size_t)(c->nacquired - 1));
        c->nacquired--;
    }
    return r;
}

/* OpenGL: each view corrected straight into the acquired output image, on the engine's own context,
 * which shares the application's textures (the engine makes it current around each view, ordered
 * after the application's rendering by a fence, and puts the application's context back). Returns 1
 * when every view was corrected. */
static int gl_correct_views(const FrameView *views, uint32_t nviews) {
    if (gl.GetCurrentContext() != L.context) {
        pass_reason("the session's GLX context is not current at xrEndFrame");
        return 0;
    }
    int ok = 1;
    for (uint32_t i = 0; i < nviews && ok; i++) {
        const FrameView *f = &views[i];
        Chain *c = f->chain;
        PyObject *res = engine_call("correct", "(IIiIIiiiiIi)", f->index, c->app_tex[c->released], (int)c->format,
                                    c->width, c->height, f->rect.offset.x, f->rect.offset.y, f->rect.extent.width,
                                    f->rect.extent.height, c->out_tex[c->out_index], (int)f->view);
        if (!res || !PyObject_IsTrue(res)) ok = 0;
        Py_XDECREF(res);
    }
    return ok;
}

/* OpenGL: each view's submitted rect handed to the engine (which copies it off this thread, ordered by a
 * fence), the frame then passing through. */
static void gl_capture_views(const FrameView *views, uint32_t nviews) {
    if (gl.GetCurrentContext() != L.context) return;
    for (uint32_t i = 0; i < nviews; i++) {
        const FrameView *f = &views[i];
        Chain *c = f->chain;
        PyObject *res = engine_call("capture_gl", "(IIiIIiiiiI)", f->index, c->app_tex[c->released], (int)c->format,
                                    c->width, c->height, f->rect.offset.x, f->rect.offset.y, f->rect.extent.width,
                                    f->rect.extent.height, f->view);
        Py_XDECREF(res);
    }
}

/* Collects the frame's projection views; 0 when the frame passes through (the reason logged). */
static int collect_views(const XrFrameEndInfo *info, FrameView *views, uint32_t *nviews) {
    if (info->layerCount > MAX_LAYERS) { pass_reason("more than 16 composition layers"); return 0; }
    uint32_t n = 0;
    for (uint32_t k = 0; k < info->layerCount; k++) {
        const XrCompositionLayerBaseHeader *b = info->layers[k];
        if (!b || b->type != XR_TYPE_COMPOSITION_LAYER_PROJECTION) continue;
        const XrCompositionLayerProjection *p = (const XrCompositionLayerProjection *)b;
        if (p->viewCount > MAX_VIEWS) { pass_reason("a projection layer with more than 4 views"); return 0; }
        for (uint32_t v = 0; v < p->viewCount; v++) {
            Chain *c = chain_of(p->views[v].subImage.swapchain);
            if (!c || c->out == XR_NULL_HANDLE) return 0;     /* the reason was logged at xrCreateSwapchain */
            if (c->released < 0) { pass_reason("a view's swapchain has no released image"); return 0; }
            if (p->views[v].subImage.imageArrayIndex != 0) { pass_reason("imageArrayIndex != 0"); return 0; }
            XrRect2Di rect = p->views[v].subImage.imageRect;
            if (rect.offset.x < 0 || rect.offset.y < 0 || rect.extent.width < 1 || rect.extent.height < 1 ||
                (uint32_t)(rect.offset.x + rect.extent.width) > c->width ||
                (uint32_t)(rect.offset.y + rect.extent.height) > c->height) {
                pass_reason("a view's imageRect lies outside its swapchain image");
                return 0;
            }
            views[n] = (FrameView){k, v, n, c, rect};
            n++;
        }
    }
    *nviews = n;
    return n > 0;
}

/* Acquires (and waits for) the output image of every chain the frame's views use, once each. */
int acquire_outputs(const FrameView *views, uint32_t nviews, Chain **acquired, int *nacq) {
    for (uint32_t i = 0; i < nviews; i++) {
        Chain *c = views[i].chain;
        int have = 0;
        for (int a = 0; a < *nacq; a++) have |= acquired[a] == c;
        if (have) continue;
        uint32_t idx = 0;
        if (XR_FAILED(L.AcquireSwapchainImage(c->out, NULL, &idx))) {
            pass_reason("could not acquire an output swapchain image");
            return 0;
        }
        c->out_index = idx;
        acquired[(*nacq)++] = c;
        XrSwapchainImageWaitInfo wait = {XR_TYPE_SWAPCHAIN_IMAGE_WAIT_INFO, NULL, XR_INFINITE_DURATION};
        if (XR_FAILED(L.WaitSwapchainImage(c->out, &wait))) {
            pass_reason("waiting for an output image failed");
            return 0;
        }
    }
    return 1;
}

/* Corrects every view; fills the copies. Returns 1 when the frame goes down corrected. */
static int correct_frame(const XrFrameEndInfo *info, XrCompositionLayerProjection *layers,
                         XrCompositionLayerProjectionView (*copies)[MAX_VIEWS], const XrCompositionLayerBaseHeader **list) {
    if (L.api == API_NONE) return 0;
    if (L.python_failed || L.engine_failed || !L.engine) return 0;   /* logged when it happened */
    FrameView views[MAX_LAYERS * MAX_VIEWS];
    uint32_t nviews = 0;
    if (!collect_views(info, views, &nviews)) return 0;
    double t0 = now_ms();
    PyGILState_STATE g = PyGILState_Ensure();
    double gil_ms = now_ms() - t0;              /* waiting for Python's lock (another thread of this process) */
    PyObject *go = engine_call("begin_frame", "()");
    long mode = go ? PyLong_AsLong(go) : 0;     /* 0: pass through (off, no prescription, ...: the engine logs why),
                                                   1: correct, 2: let the engine capture the views, pass through */
    Py_XDECREF(go);
    PyErr_Clear();
    int ok = mode == 1 || mode == 3;             /* 3: correct, ordered by external semaphores (Vulkan) */
    if (ok) gaze_views(info, views, nviews);     /* where each view's fovea goes this frame */
    if (mode == 2) {            /* the engine prepares its correction on this frame's views, off this thread */
        if (L.api == API_GL) gl_capture_views(views, nviews);
        else vk_capture_views(views, nviews);
        PyObject *done = engine_call("end_frame", "(i(dddd))", 0, now_ms() - t0, -1.0, -1.0, -1.0);
        Py_XDECREF(done);
    }
    if (!ok) {
        PyGILState_Release(g);
        double held = now_ms() - t0;
        if (held > HELD_MS)      /* a frame the layer passed through but held up: say how long, and on what */
            layer_log("a passed-through xrEndFrame held %.0f ms by the layer (%.0f ms of it waiting for Python's lock)",
                      held, gil_ms);
        return 0;
    }
    Chain *acquired[MAX_LAYERS * MAX_VIEWS];
    int nacq = 0;
    double sync_ms[3] = {-1, -1, -1};               /* Vulkan: copy in and wait, glFinish, copy out */
    if (L.api == API_GL) {
        ok = acquire_outputs(views, nviews, acquired, &nacq) && gl_correct_views(views, nviews);
    } else {
        ok = vk_correct_views(views, nviews, acquired, &nacq, sync_ms, mode == 3);   /* acquires the outputs after the GL work */
    }
    for (int a = 0; a < nacq; a++) L.ReleaseSwapchainImage(acquired[a]->out, NULL);
    /* the layer's time in this xrEndFrame (the correction, and for Vulkan the copies and waits) */
    PyObject *done = engine_call("end_frame", "(i(dddd))", ok, now_ms() - t0, sync_ms[0], sync_ms[1], sync_ms[2]);
    Py_XDECREF(done);
    PyGILState_Release(g);
    if (!ok) return 0;
    for (uint32_t k = 0; k < info->layerCount; k++) list[k] = info->layers[k];
    for (uint32_t i = 0; i < nviews; i++) {
        const FrameView *f = &views[i];
        const XrCompositionLayerProjection *p = (const XrCompositionLayerProjection *)info->layers[f->layer];
        layers[f->layer] = *p;
        copies[f->layer][f->view] = p->views[f->view];
        copies[f->layer][f->view].subImage.swapchain = f->chain->out;
        layers[f->layer].views = copies[f->layer];
        list[f->layer] = (const XrCompositionLayerBaseHeader *)&layers[f->layer];
    }
    L.last_reason[0] = 0;
    return 1;
}

static XrResult XRAPI_CALL layer_EndFrame(XrSession session, const XrFrameEndInfo *info) {
    if (session != L.session || !info || info->layerCount == 0) return L.EndFrame(session, info);
    XrCompositionLayerProjection layers[MAX_LAYERS];
    XrCompositionLayerProjectionView copies[MAX_LAYERS][MAX_VIEWS];
    const XrCompositionLayerBaseHeader *list[MAX_LAYERS];
    pthread_mutex_lock(&lock);
    int corrected = correct_frame(info, layers, copies, list);
    pthread_mutex_unlock(&lock);
    if (!corrected) return L.EndFrame(session, info);
    XrFrameEndInfo copy = *info;
    copy.layers = list;
    return L.EndFrame(session, &copy);
}

/* ------------------------------------------------------------------ dispatch and negotiation */
static XrResult XRAPI_CALL layer_GetInstanceProcAddr(XrInstance instance, const char *name, PFN_xrVoidFunction *function) {
    if (!name || !function) return XR_ERROR_VALIDATION_FAILURE;
#define HOOK(n) if (strcmp(name, "xr" #n) == 0) { \
        if (instance != XR_NULL_HANDLE && !L.n) return L.next_gipa(instance, name, function); \
        *function = (PFN_xrVoidFunction)layer_##n; return XR_SUCCESS; }
    if (strcmp(name, "xrGetInstanceProcAddr") == 0) {
        *function = (PFN_xrVoidFunction)layer_GetInstanceProcAddr;
        return XR_SUCCESS;
    }
    if (L.next_gipa && instance != XR_NULL_HANDLE) {
        HOOK(DestroyInstance) HOOK(CreateSession) HOOK(DestroySession) HOOK(CreateSwapchain) HOOK(DestroySwapchain)
        HOOK(AcquireSwapchainImage) HOOK(ReleaseSwapchainImage) HOOK(EndFrame)
        PFN_xrVoidFunction hook = vk_hook(name);          /* NULL unless the application enabled the extension */
        if (!hook) hook = gaze_hook(name);                /* NULL unless the layer asked for the eye tracker */
        if (hook) {
            *function = hook;
            return XR_SUCCESS;
        }
    }
#undef HOOK
    if (!L.next_gipa) return XR_ERROR_HANDLE_INVALID;
    return L.next_gipa(instance, name, function);
}

/* xrCreateInstance down the chain (vrcorrect_gaze.c may call it twice: with the eye tracker, then without) */
struct Down { LayerApiLayerNextInfo *mine; LayerApiLayerCreateInfo *down; XrInstance *instance; };

static XrResult create_down(const XrInstanceCreateInfo *info, void *context) {
    struct Down *d = context;
    return d->mine->nextCreateApiLayerInstance(info, d->down, d->instance);
}

static XrResult XRAPI_CALL layer_CreateApiLayerInstance(const XrInstanceCreateInfo *info,
                                                        const LayerApiLayerCreateInfo *layer_info, XrInstance *instance) {
    if (!layer_info || !layer_info->nextInfo || strcmp(layer_info->nextInfo->layerName, LAYER_NAME) != 0)
        return XR_ERROR_INITIALIZATION_FAILED;
    LayerApiLayerNextInfo *mine = layer_info->nextInfo;
    LayerApiLayerCreateInfo down = *layer_info;
    down.nextInfo = mine->next;
    struct Down context = {mine, &down, instance};
    XrResult r = gaze_create_instance(info, create_down, &context);   /* with the eye tracker, when a fovea asks */
    if (XR_FAILED(r)) return r;
    memset(&L, 0, sizeof L);
    L.next_gipa = mine->nextGetInstanceProcAddr;
    L.instance = *instance;
#define NEXT(n) if (XR_FAILED(L.next_gipa(*instance, "xr" #n, (PFN_xrVoidFunction *)&L.n))) L.n = NULL;
    NEXT(DestroyInstance) NEXT(CreateSession) NEXT(DestroySession) NEXT(CreateSwapchain) NEXT(DestroySwapchain)
    NEXT(EnumerateSwapchainImages) NEXT(AcquireSwapchainImage) NEXT(WaitSwapchainImage) NEXT(ReleaseSwapchainImage)
    NEXT(EndFrame) NEXT(EnumerateViewConfigurationViews)
#undef NEXT
    vk_fetch_next(*instance);
    gaze_start(*instance);
    return r;
}

EXPORT XrResult XRAPI_CALL xrNegotiateLoaderApiLayerInterface(const LayerNegotiateLoaderInfo *loader, const char *name,
                                                              LayerNegotiateApiLayerRequest *request) {
    if (!loader || !request || loader->structType != LOADER_STRUCT_LOADER_INFO ||
        request->structType != LOADER_STRUCT_API_LAYER_REQUEST || loader->minInterfaceVersion > 1 ||
        loader->maxInterfaceVersion < 1)
        return XR_ERROR_INITIALIZATION_FAILED;
    if (name && strcmp(name, LAYER_NAME) != 0) return XR_ERROR_INITIALIZATION_FAILED;
    request->layerInterfaceVersion = 1;
    request->layerApiVersion = XR_CURRENT_API_VERSION;
    request->getInstanceProcAddr = layer_GetInstanceProcAddr;
    request->createApiLayerInstance = layer_CreateApiLayerInstance;
    return XR_SUCCESS;
}
