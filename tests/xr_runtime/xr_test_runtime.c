/* A minimal OpenXR runtime for vrcorrect's tests (test equipment, not a product).
 *
 * Loaded by the real OpenXR loader (pyopenxr's) through a runtime manifest named by
 * XR_RUNTIME_JSON; tests/test_xr.py compiles it with the machine's C compiler. It implements
 * the calls `vrcorrect xr` makes: one instance, one head-mounted system with a stereo view
 * configuration, XR_KHR_opengl_enable (Xlib/GLX binding), reference spaces, OpenGL swapchains
 * whose textures are made in the application's current GL context, the event queue with the
 * session state machine, and the frame loop. At xrEndFrame it reads each projection view's
 * submitted image back (glGetTexImage) and writes it as a .npy file.
 *
 * No OpenXR or GL headers are needed: the few types are declared here (layouts checked below
 * against the OpenXR 1.0 headers' sizes on LP64). GL is reached through libGL.so.1 (dlopen).
 *
 * Environment (all optional):
 *   XRTEST_OUT_DIR      write runtime.log (calls and state changes, one a line) and
 *                       frame_NNNNN_view_V.npy (uint8 (H, W, 4), top row first) there
 *   XRTEST_VIEW_SIZE    recommended size of each view, WxH (default 256x256)
 *   XRTEST_FORMATS      swapchain formats offered, in order: "srgb,rgba8" (default), "rgba8", ...; names
 *                       srgb (GL_SRGB8_ALPHA8), rgba8 (GL_RGBA8), rgba16f (GL_RGBA16F)
 *   XRTEST_LOSS_AFTER   after this many xrEndFrame calls the session goes LOSS_PENDING
 *   XRTEST_STOP_AFTER   after this many xrEndFrame calls the runtime asks the app to quit
 *   XRTEST_YAW_MRAD     the head turns left about the vertical axis through its centre by this many
 *                       milliradians per xrEndFrame call (default 0: a still head)
 *                       (FOCUSED -> VISIBLE -> SYNCHRONIZED -> STOPPING, then IDLE -> EXITING)
 *   XRTEST_NO_HMD       "1": xrGetSystem answers XR_ERROR_FORM_FACTOR_UNAVAILABLE
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <math.h>
#include <time.h>

/* ------------------------------------------------------------------ OpenXR types */
typedef int32_t XrResult;
typedef uint64_t XrVersion, XrFlags64, XrSystemId;
typedef int64_t XrTime, XrDuration;
typedef uint32_t XrBool32;
typedef uint64_t XrHandle; /* every handle: a number here */
typedef void (*PFN_xrVoidFunction)(void);

#define XR_MAKE_VERSION(a, b, c) ((((uint64_t)(a)) << 48) | (((uint64_t)(b)) << 32) | (uint64_t)(c))
#define XR_MAJOR(v) ((uint16_t)((v) >> 48))
#define XR_MINOR(v) ((uint16_t)((v) >> 32))

enum {
    XR_SUCCESS = 0, XR_SESSION_LOSS_PENDING = 3, XR_EVENT_UNAVAILABLE = 4, XR_FRAME_DISCARDED = 9,
    XR_ERROR_VALIDATION_FAILURE = -1, XR_ERROR_RUNTIME_FAILURE = -2, XR_ERROR_API_VERSION_UNSUPPORTED = -4,
    XR_ERROR_FUNCTION_UNSUPPORTED = -7, XR_ERROR_EXTENSION_NOT_PRESENT = -9, XR_ERROR_SIZE_INSUFFICIENT = -11,
    XR_ERROR_HANDLE_INVALID = -12, XR_ERROR_LIMIT_REACHED = -10, XR_ERROR_SESSION_RUNNING = -14,
    XR_ERROR_SESSION_NOT_RUNNING = -16, XR_ERROR_SESSION_LOST = -17, XR_ERROR_SYSTEM_INVALID = -18,
    XR_ERROR_LAYER_INVALID = -23, XR_ERROR_SWAPCHAIN_RECT_INVALID = -25, XR_ERROR_SWAPCHAIN_FORMAT_UNSUPPORTED = -26,
    XR_ERROR_SESSION_NOT_READY = -28, XR_ERROR_SESSION_NOT_STOPPING = -29, XR_ERROR_TIME_INVALID = -30,
    XR_ERROR_REFERENCE_SPACE_UNSUPPORTED = -31, XR_ERROR_FORM_FACTOR_UNSUPPORTED = -34,
    XR_ERROR_FORM_FACTOR_UNAVAILABLE = -35, XR_ERROR_CALL_ORDER_INVALID = -37, XR_ERROR_GRAPHICS_DEVICE_INVALID = -38,
    XR_ERROR_VIEW_CONFIGURATION_TYPE_UNSUPPORTED = -41, XR_ERROR_ENVIRONMENT_BLEND_MODE_UNSUPPORTED = -42,
    XR_ERROR_GRAPHICS_REQUIREMENTS_CALL_MISSING = -50,
};
enum {
    XR_TYPE_EXTENSION_PROPERTIES = 2, XR_TYPE_INSTANCE_PROPERTIES = 32, XR_TYPE_SYSTEM_PROPERTIES = 5,
    XR_TYPE_VIEW_CONFIGURATION_VIEW = 41, XR_TYPE_VIEW_CONFIGURATION_PROPERTIES = 45,
    XR_TYPE_GRAPHICS_REQUIREMENTS_OPENGL_KHR = 1000023005, XR_TYPE_GRAPHICS_BINDING_OPENGL_XLIB_KHR = 1000023001,
    XR_TYPE_SWAPCHAIN_IMAGE_OPENGL_KHR = 1000023004, XR_TYPE_EVENT_DATA_SESSION_STATE_CHANGED = 18,
    XR_TYPE_EVENT_DATA_INSTANCE_LOSS_PENDING = 17, XR_TYPE_FRAME_STATE = 44, XR_TYPE_VIEW_STATE = 11,
    XR_TYPE_VIEW = 7, XR_TYPE_COMPOSITION_LAYER_PROJECTION = 35,
};
enum { IDLE = 1, READY, SYNCHRONIZED, VISIBLE, FOCUSED, STOPPING, LOSS_PENDING, EXITING };
static const char *STATE_NAMES[] = {"UNKNOWN", "IDLE", "READY", "SYNCHRONIZED", "VISIBLE", "FOCUSED",
                                    "STOPPING", "LOSS_PENDING", "EXITING"};
#define STEREO 2
#define HMD 1
#define OPAQUE_BLEND 1
#define GL_SRGB8_ALPHA8 0x8C43
#define GL_RGBA8 0x8058
#define GL_RGBA16F 0x881A

typedef struct { int32_t type; const void *next; } XrBase;
typedef struct { float x, y, z, w; } XrQuaternionf;
typedef struct { float x, y, z; } XrVector3f;
typedef struct { XrQuaternionf orientation; XrVector3f position; } XrPosef;
typedef struct { float angleLeft, angleRight, angleUp, angleDown; } XrFovf;
typedef struct { char applicationName[128]; uint32_t applicationVersion; char engineName[128];
                 uint32_t engineVersion; XrVersion apiVersion; } XrApplicationInfo;
typedef struct { int32_t type; const void *next; XrFlags64 createFlags; XrApplicationInfo applicationInfo;
                 uint32_t enabledApiLayerCount; const char *const *enabledApiLayerNames;
                 uint32_t enabledExtensionCount; const char *const *enabledExtensionNames; } XrInstanceCreateInfo;
typedef struct { int32_t type; void *next; char extensionName[128]; uint32_t extensionVersion; } XrExtensionProperties;
typedef struct { int32_t type; void *next; XrVersion runtimeVersion; char runtimeName[128]; } XrInstanceProperties;
typedef struct { int32_t type; const void *next; int32_t formFactor; } XrSystemGetInfo;
typedef struct { int32_t type; void *next; XrSystemId systemId; uint32_t vendorId; char systemName[256];
                 uint32_t maxSwapchainImageHeight, maxSwapchainImageWidth, maxLayerCount;
                 XrBool32 orientationTracking, positionTracking; } XrSystemProperties;
typedef struct { int32_t type; void *next; int32_t viewConfigurationType; XrBool32 fovMutable; } XrViewConfigurationProperties;
typedef struct { int32_t type; void *next; uint32_t recommendedImageRectWidth, maxImageRectWidth,
                 recommendedImageRectHeight, maxImageRectHeight, recommendedSwapchainSampleCount,
                 maxSwapchainSampleCount; } XrViewConfigurationView;
typedef struct { int32_t type; void *next; XrVersion minApiVersionSupported, maxApiVersionSupported; } XrGraphicsRequirementsOpenGLKHR;
typedef struct { int32_t type; const void *next; XrFlags64 createFlags; XrSystemId systemId; } XrSessionCreateInfo;
typedef struct { int32_t type; const void *next; void *xDisplay; uint32_t visualid; void *glxFBConfig;
                 unsigned long glxDrawable; void *glxContext; } XrGraphicsBindingOpenGLXlibKHR;
typedef struct { int32_t type; const void *next; int32_t referenceSpaceType; XrPosef poseInReferenceSpace; } XrReferenceSpaceCreateInfo;
typedef struct { int32_t type; const void *next; XrFlags64 createFlags, usageFlags; int64_t format;
                 uint32_t sampleCount, width, height, faceCount, arraySize, mipCount; } XrSwapchainCreateInfo;
typedef struct { int32_t type; void *next; uint32_t image; } XrSwapchainImageOpenGLKHR;
typedef struct { int32_t type; const void *next; XrDuration timeout; } XrSwapchainImageWaitInfo;
typedef struct { int32_t type; const void *next; uint8_t varying[4000]; } XrEventDataBuffer;
typedef struct { int32_t type; const void *next; XrHandle session; int32_t state; XrTime time; } XrEventDataSessionStateChanged;
typedef struct { int32_t type; const void *next; XrTime lossTime; } XrEventDataInstanceLossPending;
typedef struct { int32_t type; const void *next; int32_t primaryViewConfigurationType; } XrSessionBeginInfo;
typedef struct { int32_t type; void *next; XrTime predictedDisplayTime; XrDuration predictedDisplayPeriod;
                 XrBool32 shouldRender; } XrFrameState;
typedef struct { int32_t x, y; } XrOffset2Di;
typedef struct { int32_t width, height; } XrExtent2Di;
typedef struct { XrHandle swapchain; XrOffset2Di offset; XrExtent2Di extent; uint32_t imageArrayIndex; } XrSwapchainSubImage;
typedef struct { int32_t type; const void *next; XrPosef pose; XrFovf fov; XrSwapchainSubImage subImage; } XrCompositionLayerProjectionView;
typedef struct { int32_t type; const void *next; XrFlags64 layerFlags; XrHandle space; uint32_t viewCount;
                 const XrCompositionLayerProjectionView *views; } XrCompositionLayerProjection;
typedef struct { int32_t type; const void *next; XrTime displayTime; int32_t environmentBlendMode;
                 uint32_t layerCount; const XrBase *const *layers; } XrFrameEndInfo;
typedef struct { int32_t type; const void *next; int32_t viewConfigurationType; XrTime displayTime; XrHandle space; } XrViewLocateInfo;
typedef struct { int32_t type; void *next; XrFlags64 viewStateFlags; } XrViewState;
typedef struct { int32_t type; void *next; XrPosef pose; XrFovf fov; } XrView;

_Static_assert(sizeof(XrInstanceCreateInfo) == 328, "XrInstanceCreateInfo layout");
_Static_assert(sizeof(XrSystemProperties) == 304, "XrSystemProperties layout");
_Static_assert(sizeof(XrGraphicsBindingOpenGLXlibKHR) == 56, "binding layout");
_Static_assert(sizeof(XrSwapchainCreateInfo) == 64, "XrSwapchainCreateInfo layout");
_Static_assert(sizeof(XrCompositionLayerProjectionView) == 96, "projection view layout");
_Static_assert(offsetof(XrCompositionLayerProjectionView, subImage) == 64, "projection view layout");
_Static_assert(sizeof(XrFrameEndInfo) == 40 && sizeof(XrFrameState) == 40 && sizeof(XrView) == 64, "layouts");
_Static_assert(offsetof(XrReferenceSpaceCreateInfo, poseInReferenceSpace) == 20, "space layout");
_Static_assert(sizeof(XrEventDataSessionStateChanged) == 40, "event layout");

/* Loader negotiation (openxr_loader_negotiation.h) */
typedef XrResult (*PFN_xrGetInstanceProcAddr)(XrHandle, const char *, PFN_xrVoidFunction *);
typedef struct { int32_t structType; uint32_t structVersion; size_t structSize; uint32_t minInterfaceVersion,
                 maxInterfaceVersion; XrVersion minApiVersion, maxApiVersion; } XrNegotiateLoaderInfo;
typedef struct { int32_t structType; uint32_t structVersion; size_t structSize; uint32_t runtimeInterfaceVersion;
                 XrVersion runtimeApiVersion; PFN_xrGetInstanceProcAddr getInstanceProcAddr; } XrNegotiateRuntimeRequest;

/* ------------------------------------------------------------------ GL through libGL.so.1 */
typedef unsigned int GLuint;
typedef int GLint;
typedef unsigned int GLenum;
#define GL_TEXTURE_2D 0x0DE1
#define GL_TEXTURE_BINDING_2D 0x8069
#define GL_PIXEL_PACK_BUFFER 0x88EB
#define GL_PIXEL_PACK_BUFFER_BINDING 0x88ED
#define GL_PACK_ALIGNMENT 0x0D05
#define GL_TEXTURE_MIN_FILTER 0x2801
#define GL_TEXTURE_MAG_FILTER 0x2800
#define GL_TEXTURE_MAX_LEVEL 0x813D
#define GL_LINEAR 0x2601
#define GL_RGBA 0x1908
#define GL_UNSIGNED_BYTE 0x1401
static struct {
    void *(*GetCurrentContext)(void);
    void (*GetIntegerv)(GLenum, GLint *);
    void (*GenTextures)(int, GLuint *);
    void (*DeleteTextures)(int, const GLuint *);
    void (*BindTexture)(GLenum, GLuint);
    void (*TexImage2D)(GLenum, GLint, GLint, int, int, GLint, GLenum, GLenum, const void *);
    void (*TexParameteri)(GLenum, GLenum, GLint);
    void (*GetTexImage)(GLenum, GLint, GLenum, GLenum, void *);
    void (*PixelStorei)(GLenum, GLint);
    void (*BindBuffer)(GLenum, GLuint);
} gl;

static int load_gl(void) {
    if (gl.GetTexImage) return 1;
    void *lib = dlopen("libGL.so.1", RTLD_NOW | RTLD_GLOBAL);
    if (!lib) return 0;
    void *(*gpa)(const char *) = (void *(*)(const char *))dlsym(lib, "glXGetProcAddressARB");
    if (!gpa) return 0;
#define GET(field, name) *(void **)&gl.field = gpa(name); if (!gl.field) return 0;
    GET(GetCurrentContext, "glXGetCurrentContext") GET(GetIntegerv, "glGetIntegerv")
    GET(GenTextures, "glGenTextures") GET(DeleteTextures, "glDeleteTextures") GET(BindTexture, "glBindTexture")
    GET(TexImage2D, "glTexImage2D") GET(TexParameteri, "glTexParameteri") GET(PixelStorei, "glPixelStorei")
    GET(BindBuffer, "glBindBuffer") GET(GetTexImage, "glGetTexImage")
#undef GET
    return 1;
}

/* ------------------------------------------------------------------ state */
#define INSTANCE ((XrHandle)0x1001)
#define SESSION ((XrHandle)0x2001)
#define SYSTEM_ID 7
#define MAX_SWAPCHAINS 8
#define IMAGES 3
#define MAX_SPACES 16
#define QUEUE 64

typedef struct { int used, width, height, format; GLuint tex[IMAGES]; int next, acquired, waited, released_index; } Swapchain;
typedef struct { int type; XrEventDataSessionStateChanged s; XrEventDataInstanceLossPending l; } Event;

static struct {
    int instance, gfx_reqs, session, state, running, exit_requested, quit_after_stop;
    int frame_waited, frame_begun, view_w, view_h, nformats;
    int64_t formats[4];
    long end_frames, loss_after, stop_after;
    double yaw_per_frame;
    XrTime t0, next_display;
    Swapchain sc[MAX_SWAPCHAINS];
    int spaces[MAX_SPACES];
    Event queue[QUEUE];
    int qhead, qtail;
    char out_dir[1024];
} rt;

static const XrDuration PERIOD_NS = 11111111; /* 90 Hz */

static XrTime now_ns(void) {
    struct timespec ts;
    clock_gettime(CLOCK_MONOTONIC, &ts);
    return (XrTime)ts.tv_sec * 1000000000LL + ts.tv_nsec;
}

static void logf_(const char *fmt, ...) {
    if (!rt.out_dir[0]) return;
    char path[1100];
    snprintf(path, sizeof path, "%s/runtime.log", rt.out_dir);
    FILE *f = fopen(path, "a");
    if (!f) return;
    va_list ap;
    va_start(ap, fmt);
    vfprintf(f, fmt, ap);
    va_end(ap);
    fputc('\n', f);
    fclose(f);
}

static long env_long(const char *name, long fallback) {
    const char *v = getenv(name);
    return v && *v ? strtol(v, NULL, 10) : fallback;
}

static void push_state(int state) {
    rt.state = state;
    logf_("state %s", STATE_NAMES[state]);
    Event *e = &rt.queue[rt.qtail % QUEUE];
    rt.qtail++;
    e->type = XR_TYPE_EVENT_DATA_SESSION_STATE_CHANGED;
    e->s = (XrEventDataSessionStateChanged){XR_TYPE_EVENT_DATA_SESSION_STATE_CHANGED, NULL, SESSION, state, now_ns()};
}

/* the count-then-fill idiom of every xrEnumerate* call */
#define ENUMERATE(cap, count_out, n, ...) do { \
        if (!(count_out)) return XR_ERROR_VALIDATION_FAILURE; \
        *(count_out) = (n); \
        if ((cap) == 0) return XR_SUCCESS; \
        if ((cap) < (uint32_t)(n)) return XR_ERROR_SIZE_INSUFFICIENT; \
        for (uint32_t i = 0; i < (uint32_t)(n); i++) { __VA_ARGS__; } \
        return XR_SUCCESS; } while (0)

/* ------------------------------------------------------------------ instance and system */
static XrResult enumerate_instance_extension_properties(const char *layer, uint32_t cap, uint32_t *count,
                                                        XrExtensionProperties *props) {
    if (layer && *layer) return XR_ERROR_LAYER_INVALID;
    ENUMERATE(cap, count, 1, {
        strcpy(props[i].extensionName, "XR_KHR_opengl_enable");
        props[i].extensionVersion = 10;
    });
}


/* XRTEST_FORMATS' names: "srgb" (GL_SRGB8_ALPHA8), "rgba8" (GL_RGBA8), "rgba16f" (GL_RGBA16F: half floats,
 * dumped clamped to [0, 1] as 8-bit values by glGetTexImage); 0 for any other name */
static int64_t format_named(const char *name, size_t n) {
    if (n == 4 && strncmp(name, "srgb", n) == 0) return GL_SRGB8_ALPHA8;
    if (n == 5 && strncmp(name, "rgba8", n) == 0) return GL_RGBA8;
    if (n == 7 && strncmp(name, "rgba16f", n) == 0) return GL_RGBA16F;
    return 0;
}

static XrResult create_instance(const XrInstanceCreateInfo *info, XrHandle *instance) {
    if (!info || !instance) return XR_ERROR_VALIDATION_FAILURE;
    if (rt.instance) return XR_ERROR_LIMIT_REACHED;
    XrVersion v = info->applicationInfo.apiVersion;
    if (XR_MAJOR(v) != 1 || XR_MINOR(v) > 1) return XR_ERROR_API_VERSION_UNSUPPORTED;
    for (uint32_t i = 0; i < info->enabledExtensionCount; i++)
        if (strcmp(info->enabledExtensionNames[i], "XR_KHR_opengl_enable") != 0) return XR_ERROR_EXTENSION_NOT_PRESENT;
    memset(&rt, 0, sizeof rt);
    const char *out = getenv("XRTEST_OUT_DIR");
    if (out) snprintf(rt.out_dir, sizeof rt.out_dir, "%s", out);
    rt.view_w = rt.view_h = 256;
    const char *size = getenv("XRTEST_VIEW_SIZE");
    if (size && (sscanf(size, "%dx%d", &rt.view_w, &rt.view_h) != 2 || rt.view_w < 1 || rt.view_h < 1))
        return XR_ERROR_RUNTIME_FAILURE;
    const char *formats = getenv("XRTEST_FORMATS");
    if (!formats) formats = "srgb,rgba8";
    for (const char *p = formats; *p;) {          /* comma-separated names, in order; unknown names are skipped */
        p += strspn(p, " ,");
        size_t n = strcspn(p, " ,");
        int64_t f = format_named(p, n);
        int seen = 0;
        for (int i = 0; i < rt.nformats; i++) seen |= rt.formats[i] == f;
        if (f && !seen && rt.nformats < (int)(sizeof rt.formats / sizeof rt.formats[0])) rt.formats[rt.nformats++] = f;
        p += n;
    }
    rt.loss_after = env_long("XRTEST_LOSS_AFTER", 0);
    rt.stop_after = env_long("XRTEST_STOP_AFTER", 0);
    rt.yaw_per_frame = 1e-3 * (double)env_long("XRTEST_YAW_MRAD", 0);
    rt.instance = 1;
    *instance = INSTANCE;
    logf_("create_instance app=%s api=%u.%u ext=%u", info->applicationInfo.applicationName, XR_MAJOR(v), XR_MINOR(v),
          info->enabledExtensionCount);
    return XR_SUCCESS;
}

#define CHECK_INSTANCE(h) if (!rt.instance || (h) != INSTANCE) return XR_ERROR_HANDLE_INVALID
#define CHECK_SESSION(h) if (!rt.session || (h) != SESSION) return XR_ERROR_HANDLE_INVALID
#define CHECK_SYSTEM(id) if ((id) != SYSTEM_ID) return XR_ERROR_SYSTEM_INVALID

static XrResult destroy_instance(XrHandle instance) {
    CHECK_INSTANCE(instance);
    logf_("destroy_instance");
    rt.instance = 0;
    return XR_SUCCESS;
}

static XrResult get_instance_properties(XrHandle instance, XrInstanceProperties *p) {
    CHECK_INSTANCE(instance);
    p->runtimeVersion = XR_MAKE_VERSION(0, 1, 0);
    snprintf(p->runtimeName, sizeof p->runtimeName, "vrcorrect test runtime");
    return XR_SUCCESS;
}

static XrResult result_to_string(XrHandle instance, XrResult value, char buffer[64]) {
    (void)instance;
    snprintf(buffer, 64, value == 0 ? "XR_SUCCESS" : "XR_RESULT_%d", value);
    return XR_SUCCESS;
}

static XrResult structure_type_to_string(XrHandle instance, int32_t value, char buffer[64]) {
    (void)instance;
    snprintf(buffer, 64, "XR_STRUCTURE_TYPE_%d", value);
    return XR_SUCCESS;
}

static XrResult get_system(XrHandle instance, const XrSystemGetInfo *info, XrSystemId *id) {
    CHECK_INSTANCE(instance);
    if (info->formFactor != HMD) return XR_ERROR_FORM_FACTOR_UNSUPPORTED;
    if (env_long("XRTEST_NO_HMD", 0)) return XR_ERROR_FORM_FACTOR_UNAVAILABLE;
    *id = SYSTEM_ID;
    return XR_SUCCESS;
}

static XrResult get_system_properties(XrHandle instance, XrSystemId id, XrSystemProperties *p) {
    CHECK_INSTANCE(instance);
    CHECK_SYSTEM(id);
    p->systemId = id;
    p->vendorId = 0;
    snprintf(p->systemName, sizeof p->systemName, "vrcorrect test headset");
    p->maxSwapchainImageWidth = p->maxSwapchainImageHeight = 4096;
    p->maxLayerCount = 16;
    p->orientationTracking = p->positionTracking = 1;
    return XR_SUCCESS;
}

static XrResult enumerate_view_configurations(XrHandle instance, XrSystemId id, uint32_t cap, uint32_t *count,
                                              int32_t *types) {
    CHECK_INSTANCE(instance);
    CHECK_SYSTEM(id);
    ENUMERATE(cap, count, 1, types[i] = STEREO);
}

static XrResult get_view_configuration_properties(XrHandle instance, XrSystemId id, int32_t type,
                                                  XrViewConfigurationProperties *p) {
    CHECK_INSTANCE(instance);
    CHECK_SYSTEM(id);
    if (type != STEREO) return XR_ERROR_VIEW_CONFIGURATION_TYPE_UNSUPPORTED;
    p->viewConfigurationType = STEREO;
    p->fovMutable = 0;
    return XR_SUCCESS;
}

static XrResult enumerate_view_configuration_views(XrHandle instance, XrSystemId id, int32_t type, uint32_t cap,
                                                   uint32_t *count, XrViewConfigurationView *views) {
    CHECK_INSTANCE(instance);
    CHECK_SYSTEM(id);
    if (type != STEREO) return XR_ERROR_VIEW_CONFIGURATION_TYPE_UNSUPPORTED;
    ENUMERATE(cap, count, 2, {
        views[i].recommendedImageRectWidth = (uint32_t)rt.view_w;
        views[i].recommendedImageRectHeight = (uint32_t)rt.view_h;
        views[i].maxImageRectWidth = views[i].maxImageRectHeight = 4096;
        views[i].recommendedSwapchainSampleCount = views[i].maxSwapchainSampleCount = 1;
    });
}

static XrResult enumerate_environment_blend_modes(XrHandle instance, XrSystemId id, int32_t type, uint32_t cap,
                                                  uint32_t *count, int32_t *modes) {
    CHECK_INSTANCE(instance);
    CHECK_SYSTEM(id);
    if (type != STEREO) return XR_ERROR_VIEW_CONFIGURATION_TYPE_UNSUPPORTED;
    ENUMERATE(cap, count, 1, modes[i] = OPAQUE_BLEND);
}

static XrResult get_opengl_graphics_requirements(XrHandle instance, XrSystemId id, XrGraphicsRequirementsOpenGLKHR *r) {
    CHECK_INSTANCE(instance);
    CHECK_SYSTEM(id);
    r->minApiVersionSupported = XR_MAKE_VERSION(3, 3, 0);
    r->maxApiVersionSupported = XR_MAKE_VERSION(4, 6, 0);
    rt.gfx_reqs = 1;
    logf_("graphics_requirements");
    return XR_SUCCESS;
}

/* ------------------------------------------------------------------ session */
static XrResult create_session(XrHandle instance, const XrSessionCreateInfo *info, XrHandle *session) {
    CHECK_INSTANCE(instance);
    CHECK_SYSTEM(info->systemId);
    if (!rt.gfx_reqs) return XR_ERROR_GRAPHICS_REQUIREMENTS_CALL_MISSING;
    if (rt.session) return XR_ERROR_LIMIT_REACHED;
    const XrGraphicsBindingOpenGLXlibKHR *binding = NULL;
    for (const XrBase *b = info->next; b; b = b->next)
        if (b->type == XR_TYPE_GRAPHICS_BINDING_OPENGL_XLIB_KHR) binding = (const XrGraphicsBindingOpenGLXlibKHR *)b;
    if (!binding || !binding->xDisplay || !binding->glxContext || !binding->glxDrawable) return XR_ERROR_GRAPHICS_DEVICE_INVALID;
    if (!load_gl()) return XR_ERROR_RUNTIME_FAILURE;
    if (gl.GetCurrentContext() != binding->glxContext) {
        logf_("create_session: the binding's GLX context is not current");
        return XR_ERROR_GRAPHICS_DEVICE_INVALID;
    }
    rt.session = 1;
    rt.t0 = now_ns();
    *session = SESSION;
    logf_("create_session");
    push_state(IDLE);
    push_state(READY);
    return XR_SUCCESS;
}

static XrResult destroy_session(XrHandle session) {
    CHECK_SESSION(session);
    for (int i = 0; i < MAX_SWAPCHAINS; i++)
        if (rt.sc[i].used) logf_("destroy_session: swapchain %d still alive", i);
    rt.session = rt.running = 0;
    logf_("destroy_session");
    return XR_SUCCESS;
}

static XrResult enumerate_reference_spaces(XrHandle session, uint32_t cap, uint32_t *count, int32_t *types) {
    CHECK_SESSION(session);
    ENUMERATE(cap, count, 3, types[i] = (int32_t)i + 1); /* VIEW, LOCAL, STAGE */
}

static XrResult create_reference_space(XrHandle session, const XrReferenceSpaceCreateInfo *info, XrHandle *space) {
    CHECK_SESSION(session);
    if (info->referenceSpaceType < 1 || info->referenceSpaceType > 3) return XR_ERROR_REFERENCE_SPACE_UNSUPPORTED;
    for (int i = 0; i < MAX_SPACES; i++)
        if (!rt.spaces[i]) {
            rt.spaces[i] = info->referenceSpaceType;
            *space = (XrHandle)(0x3000 + i);
            return XR_SUCCESS;
        }
    return XR_ERROR_LIMIT_REACHED;
}

static int space_index(XrHandle space) {
    int i = (int)(space - 0x3000);
    return (space >= 0x3000 && i < MAX_SPACES && rt.spaces[i]) ? i : -1;
}

static XrResult destroy_space(XrHandle space) {
    int i = space_index(space);
    if (i < 0) return XR_ERROR_HANDLE_INVALID;
    rt.spaces[i] = 0;
    return XR_SUCCESS;
}

static XrResult begin_session(XrHandle session, const XrSessionBeginInfo *info) {
    CHECK_SESSION(session);
    if (rt.running) return XR_ERROR_SESSION_RUNNING;
    if (rt.state != READY) return XR_ERROR_SESSION_NOT_READY;
    if (info->primaryViewConfigurationType != STEREO) return XR_ERROR_VIEW_CONFIGURATION_TYPE_UNSUPPORTED;
    rt.running = 1;
    logf_("begin_session");
    return XR_SUCCESS;
}

static void stop_from(int state) {
    if (state == FOCUSED) push_state(VISIBLE);
    if (state == FOCUSED || state == VISIBLE) push_state(SYNCHRONIZED);
    push_state(STOPPING);
}

static XrResult request_exit_session(XrHandle session) {
    CHECK_SESSION(session);
    if (!rt.running) return XR_ERROR_SESSION_NOT_RUNNING;
    logf_("request_exit_session");
    if (!rt.exit_requested && rt.state != STOPPING && rt.state != LOSS_PENDING) stop_from(rt.state);
    rt.exit_requested = 1;
    return XR_SUCCESS;
}

static XrResult end_session(XrHandle session) {
    CHECK_SESSION(session);
    if (!rt.running) return XR_ERROR_SESSION_NOT_RUNNING;
    if (rt.state != STOPPING) return XR_ERROR_SESSION_NOT_STOPPING;
    rt.running = 0;
    logf_("end_session");
    push_state(IDLE);
    if (rt.exit_requested || rt.quit_after_stop) push_state(EXITING);
    return XR_SUCCESS;
}

static XrResult poll_event(XrHandle instance, XrEventDataBuffer *buffer) {
    CHECK_INSTANCE(instance);
    if (rt.qhead == rt.qtail) return XR_EVENT_UNAVAILABLE;
    Event *e = &rt.queue[rt.qhead % QUEUE];
    rt.qhead++;
    if (e->type == XR_TYPE_EVENT_DATA_SESSION_STATE_CHANGED) memcpy(buffer, &e->s, sizeof e->s);
    else memcpy(buffer, &e->l, sizeof e->l);
    return XR_SUCCESS;
}

/* ------------------------------------------------------------------ swapchains */
static XrResult enumerate_swapchain_formats(XrHandle session, uint32_t cap, uint32_t *count, int64_t *formats) {
    CHECK_SESSION(session);
    ENUMERATE(cap, count, rt.nformats, formats[i] = rt.formats[i]);
}

static Swapchain *swapchain_of(XrHandle h) {
    int i = (int)(h - 0x4000);
    return (h >= 0x4000 && i < MAX_SWAPCHAINS && rt.sc[i].used) ? &rt.sc[i] : NULL;
}

static XrResult create_swapchain(XrHandle session, const XrSwapchainCreateInfo *info, XrHandle *out) {
    CHECK_SESSION(session);
    int ok = 0;
    for (int i = 0; i < rt.nformats; i++) ok |= rt.formats[i] == info->format;
    if (!ok) return XR_ERROR_SWAPCHAIN_FORMAT_UNSUPPORTED;
    if (info->width < 1 || info->height < 1 || info->width > 4096 || info->height > 4096 || info->sampleCount != 1 ||
        info->faceCount != 1 || info->arraySize != 1 || info->mipCount != 1)
        return XR_ERROR_VALIDATION_FAILURE;
    for (int i = 0; i < MAX_SWAPCHAINS; i++) {
        Swapchain *s = &rt.sc[i];
        if (s->used) continue;
        memset(s, 0, sizeof *s);
        s->used = 1;
        s->width = (int)info->width;
        s->height = (int)info->height;
        s->format = (int)info->format;
        s->released_index = -1;
        GLint previous = 0;
        gl.GetIntegerv(GL_TEXTURE_BINDING_2D, &previous);
        gl.GenTextures(IMAGES, s->tex);
        for (int k = 0; k < IMAGES; k++) {
            gl.BindTexture(GL_TEXTURE_2D, s->tex[k]);
            gl.TexImage2D(GL_TEXTURE_2D, 0, s->format, s->width, s->height, 0, GL_RGBA, GL_UNSIGNED_BYTE, NULL);
            gl.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
            gl.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
            gl.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAX_LEVEL, 0);
        }
        gl.BindTexture(GL_TEXTURE_2D, (GLuint)previous);
        *out = (XrHandle)(0x4000 + i);
        logf_("create_swapchain %d format=0x%x %dx%d", i, s->format, s->width, s->height);
        return XR_SUCCESS;
    }
    return XR_ERROR_LIMIT_REACHED;
}

static XrResult destroy_swapchain(XrHandle h) {
    Swapchain *s = swapchain_of(h);
    if (!s) return XR_ERROR_HANDLE_INVALID;
    gl.DeleteTextures(IMAGES, s->tex);
    s->used = 0;
    logf_("destroy_swapchain %d", (int)(h - 0x4000));
    return XR_SUCCESS;
}

static XrResult enumerate_swapchain_images(XrHandle h, uint32_t cap, uint32_t *count, XrSwapchainImageOpenGLKHR *images) {
    Swapchain *s = swapchain_of(h);
    if (!s) return XR_ERROR_HANDLE_INVALID;
    ENUMERATE(cap, count, IMAGES, {
        if (images[i].type != XR_TYPE_SWAPCHAIN_IMAGE_OPENGL_KHR) return XR_ERROR_VALIDATION_FAILURE;
        images[i].image = s->tex[i];
    });
}

static XrResult acquire_swapchain_image(XrHandle h, const void *info, uint32_t *index) {
    (void)info;
    Swapchain *s = swapchain_of(h);
    if (!s) return XR_ERROR_HANDLE_INVALID;
    if (s->acquired) return XR_ERROR_CALL_ORDER_INVALID; /* one at a time is all vrcorrect needs */
    s->acquired = 1;
    s->waited = 0;
    *index = (uint32_t)s->next;
    return XR_SUCCESS;
}

static XrResult wait_swapchain_image(XrHandle h, const XrSwapchainImageWaitInfo *info) {
    (void)info;
    Swapchain *s = swapchain_of(h);
    if (!s) return XR_ERROR_HANDLE_INVALID;
    if (!s->acquired || s->waited) return XR_ERROR_CALL_ORDER_INVALID;
    s->waited = 1;
    return XR_SUCCESS;
}

static XrResult release_swapchain_image(XrHandle h, const void *info) {
    (void)info;
    Swapchain *s = swapchain_of(h);
    if (!s) return XR_ERROR_HANDLE_INVALID;
    if (!s->acquired || !s->waited) return XR_ERROR_CALL_ORDER_INVALID;
    s->acquired = s->waited = 0;
    s->released_index = s->next;
    s->next = (s->next + 1) % IMAGES;
    return XR_SUCCESS;
}

/* ------------------------------------------------------------------ frames */
static XrResult wait_frame(XrHandle session, const void *info, XrFrameState *state) {
    (void)info;
    CHECK_SESSION(session);
    if (!rt.running) return XR_ERROR_SESSION_NOT_RUNNING;
    if (rt.state == READY) push_state(SYNCHRONIZED);
    rt.next_display = rt.next_display ? rt.next_display + PERIOD_NS : rt.t0 + 2 * PERIOD_NS;
    state->predictedDisplayTime = rt.next_display;
    state->predictedDisplayPeriod = PERIOD_NS;
    state->shouldRender = rt.state == VISIBLE || rt.state == FOCUSED;
    rt.frame_waited = 1;
    return rt.state == LOSS_PENDING ? XR_SESSION_LOSS_PENDING : XR_SUCCESS;
}

static XrResult begin_frame(XrHandle session, const void *info) {
    (void)info;
    CHECK_SESSION(session);
    if (!rt.running) return XR_ERROR_SESSION_NOT_RUNNING;
    if (!rt.frame_waited) return XR_ERROR_CALL_ORDER_INVALID;
    rt.frame_waited = 0;
    int discarded = rt.frame_begun;
    rt.frame_begun = 1;
    return discarded ? XR_FRAME_DISCARDED : XR_SUCCESS;
}

static void write_npy(const char *path, const uint8_t *rgba, int w, int h) {
    FILE *f = fopen(path, "wb");
    if (!f) return;
    char header[128];
    int n = snprintf(header, sizeof header, "{'descr': '|u1', 'fortran_order': False, 'shape': (%d, %d, 4), }", h, w);
    int total = ((10 + n + 1 + 63) / 64) * 64; /* magic(6) + version(2) + len(2) + header + '\n' */
    uint16_t hlen = (uint16_t)(total - 10);
    fwrite("\x93NUMPY\x01\x00", 1, 8, f);
    fputc(hlen & 0xff, f);
    fputc(hlen >> 8, f);
    fwrite(header, 1, (size_t)n, f);
    for (int i = 10 + n; i < total - 1; i++) fputc(' ', f);
    fputc('\n', f);
    for (int y = h - 1; y >= 0; y--) fwrite(rgba + (size_t)y * w * 4, 1, (size_t)w * 4, f); /* top row first */
    fclose(f);
}

static XrResult dump_view(long frame, uint32_t v, const XrCompositionLayerProjectionView *view) {
    Swapchain *s = swapchain_of(view->subImage.swapchain);
    if (!s || s->released_index < 0 || s->acquired) return XR_ERROR_LAYER_INVALID;
    XrOffset2Di o = view->subImage.offset;
    XrExtent2Di e = view->subImage.extent;
    if (o.x < 0 || o.y < 0 || e.width < 1 || e.height < 1 || o.x + e.width > s->width || o.y + e.height > s->height)
        return XR_ERROR_SWAPCHAIN_RECT_INVALID;
    if (!rt.out_dir[0]) return XR_SUCCESS;
    uint8_t *all = malloc((size_t)s->width * s->height * 4), *rect = malloc((size_t)e.width * e.height * 4);
    if (!all || !rect) { free(all); free(rect); return XR_ERROR_RUNTIME_FAILURE; }
    GLint previous = 0, pack = 0, alignment = 4;
    gl.GetIntegerv(GL_TEXTURE_BINDING_2D, &previous);
    gl.GetIntegerv(GL_PIXEL_PACK_BUFFER_BINDING, &pack);
    gl.GetIntegerv(GL_PACK_ALIGNMENT, &alignment);
    gl.BindBuffer(GL_PIXEL_PACK_BUFFER, 0);
    gl.PixelStorei(GL_PACK_ALIGNMENT, 1);
    gl.BindTexture(GL_TEXTURE_2D, s->tex[s->released_index]);
    gl.GetTexImage(GL_TEXTURE_2D, 0, GL_RGBA, GL_UNSIGNED_BYTE, all);
    gl.BindTexture(GL_TEXTURE_2D, (GLuint)previous);
    gl.PixelStorei(GL_PACK_ALIGNMENT, alignment);
    gl.BindBuffer(GL_PIXEL_PACK_BUFFER, (GLuint)pack);
    for (int y = 0; y < e.height; y++)
        memcpy(rect + (size_t)y * e.width * 4, all + ((size_t)(o.y + y) * s->width + o.x) * 4, (size_t)e.width * 4);
    char path[1200];
    snprintf(path, sizeof path, "%s/frame_%05ld_view_%u.npy", rt.out_dir, frame, v);
    write_npy(path, rect, e.width, e.height);
    free(all);
    free(rect);
    return XR_SUCCESS;
}

static XrResult end_frame(XrHandle session, const XrFrameEndInfo *info) {
    CHECK_SESSION(session);
    if (!rt.running) return XR_ERROR_SESSION_NOT_RUNNING;
    if (!rt.frame_begun) return XR_ERROR_CALL_ORDER_INVALID;
    if (info->environmentBlendMode != OPAQUE_BLEND) return XR_ERROR_ENVIRONMENT_BLEND_MODE_UNSUPPORTED;
    if (info->displayTime <= 0) return XR_ERROR_TIME_INVALID;
    rt.frame_begun = 0;
    long frame = rt.end_frames++;
    for (uint32_t k = 0; k < info->layerCount; k++) {
        const XrBase *layer = info->layers[k];
        if (!layer || layer->type != XR_TYPE_COMPOSITION_LAYER_PROJECTION) return XR_ERROR_LAYER_INVALID;
        const XrCompositionLayerProjection *p = (const XrCompositionLayerProjection *)layer;
        if (p->viewCount != 2 || space_index(p->space) < 0) return XR_ERROR_VALIDATION_FAILURE;
        for (uint32_t v = 0; v < 2; v++) {
            XrResult r = dump_view(frame, v, &p->views[v]);
            if (r != XR_SUCCESS) return r;
        }
    }
    logf_("end_frame %ld layers=%u", frame, info->layerCount);
    if (rt.state == SYNCHRONIZED && !rt.exit_requested && !rt.quit_after_stop) {
        push_state(VISIBLE);
        push_state(FOCUSED);
    }
    if (rt.loss_after && rt.end_frames == rt.loss_after) push_state(LOSS_PENDING);
    if (rt.stop_after && rt.end_frames == rt.stop_after && !rt.exit_requested && rt.state != STOPPING) {
        logf_("runtime asks the application to quit");
        rt.quit_after_stop = 1;
        stop_from(rt.state);
    }
    return rt.state == LOSS_PENDING ? XR_SESSION_LOSS_PENDING : XR_SUCCESS;
}

static XrResult locate_views(XrHandle session, const XrViewLocateInfo *info, XrViewState *state, uint32_t cap,
                             uint32_t *count, XrView *views) {
    CHECK_SESSION(session);
    if (info->viewConfigurationType != STEREO) return XR_ERROR_VIEW_CONFIGURATION_TYPE_UNSUPPORTED;
    if (info->displayTime <= 0) return XR_ERROR_TIME_INVALID;
    if (space_index(info->space) < 0) return XR_ERROR_HANDLE_INVALID;
    state->viewStateFlags = 0xF; /* orientation and position valid and tracked */
    /* LOCAL space: eyes 64 mm apart about its origin, looking down -z; each field wider on its outer side;
       the head turned left (about +y) by yaw_per_frame for every frame ended so far */
    double yaw = rt.yaw_per_frame * (double)rt.end_frames;
    float qy = (float)sin(0.5 * yaw), qw = (float)cos(0.5 * yaw), c = (float)cos(yaw), s = (float)sin(yaw);
    ENUMERATE(cap, count, 2, {
        float side = i == 0 ? -1.0f : 1.0f;
        views[i].pose = (XrPosef){{0, qy, 0, qw}, {side * 0.032f * c, 0, -side * 0.032f * s}};
        views[i].fov = i == 0 ? (XrFovf){-0.80f, 0.70f, 0.75f, -0.78f} : (XrFovf){-0.70f, 0.80f, 0.75f, -0.78f};
    });
}

/* ------------------------------------------------------------------ dispatch */
static const struct { const char *name; PFN_xrVoidFunction fn; } FUNCTIONS[] = {
#define F(name, fn) {name, (PFN_xrVoidFunction)fn}
    F("xrEnumerateInstanceExtensionProperties", enumerate_instance_extension_properties),
    F("xrCreateInstance", create_instance), F("xrDestroyInstance", destroy_instance),
    F("xrGetInstanceProperties", get_instance_properties), F("xrResultToString", result_to_string),
    F("xrStructureTypeToString", structure_type_to_string), F("xrGetSystem", get_system),
    F("xrGetSystemProperties", get_system_properties),
    F("xrEnumerateViewConfigurations", enumerate_view_configurations),
    F("xrGetViewConfigurationProperties", get_view_configuration_properties),
    F("xrEnumerateViewConfigurationViews", enumerate_view_configuration_views),
    F("xrEnumerateEnvironmentBlendModes", enumerate_environment_blend_modes),
    F("xrGetOpenGLGraphicsRequirementsKHR", get_opengl_graphics_requirements),
    F("xrCreateSession", create_session), F("xrDestroySession", destroy_session),
    F("xrEnumerateReferenceSpaces", enumerate_reference_spaces), F("xrCreateReferenceSpace", create_reference_space),
    F("xrDestroySpace", destroy_space), F("xrBeginSession", begin_session), F("xrEndSession", end_session),
    F("xrRequestExitSession", request_exit_session), F("xrPollEvent", poll_event),
    F("xrEnumerateSwapchainFormats", enumerate_swapchain_formats), F("xrCreateSwapchain", create_swapchain),
    F("xrDestroySwapchain", destroy_swapchain), F("xrEnumerateSwapchainImages", enumerate_swapchain_images),
    F("xrAcquireSwapchainImage", acquire_swapchain_image), F("xrWaitSwapchainImage", wait_swapchain_image),
    F("xrReleaseSwapchainImage", release_swapchain_image), F("xrWaitFrame", wait_frame),
    F("xrBeginFrame", begin_frame), F("xrEndFrame", end_frame), F("xrLocateViews", locate_views),
#undef F
};

static XrResult get_instance_proc_addr(XrHandle instance, const char *name, PFN_xrVoidFunction *function) {
    (void)instance;
    if (!name || !function) return XR_ERROR_VALIDATION_FAILURE;
    if (strcmp(name, "xrGetInstanceProcAddr") == 0) {
        *function = (PFN_xrVoidFunction)get_instance_proc_addr;
        return XR_SUCCESS;
    }
    for (size_t i = 0; i < sizeof FUNCTIONS / sizeof FUNCTIONS[0]; i++)
        if (strcmp(name, FUNCTIONS[i].name) == 0) {
            *function = FUNCTIONS[i].fn;
            return XR_SUCCESS;
        }
    *function = NULL;
    return XR_ERROR_FUNCTION_UNSUPPORTED;
}

__attribute__((visibility("default"))) XrResult xrNegotiateLoaderRuntimeInterface(
    const XrNegotiateLoaderInfo *loader, XrNegotiateRuntimeRequest *request) {
    if (!loader || !request || loader->structType != 1 || request->structType != 3 || loader->minInterfaceVersion > 1 ||
        loader->maxInterfaceVersion < 1)
        return XR_ERROR_VALIDATION_FAILURE;
    request->runtimeInterfaceVersion = 1;
    request->runtimeApiVersion = XR_MAKE_VERSION(1, 0, 0);
    request->getInstanceProcAddr = get_instance_proc_addr;
    return XR_SUCCESS;
}
