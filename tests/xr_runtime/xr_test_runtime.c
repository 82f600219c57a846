/* A small OpenXR runtime for vrcorrect's tests (test equipment, not a product), also the way to try
 * any OpenXR application with the vrcorrect layer without a headset:
 *
 *     XR_RUNTIME_JSON=$(tools/xr_test_runtime.sh /tmp/rt | tail -1) hello_xr -g Vulkan
 *
 * Loaded by the real OpenXR loader through a runtime manifest named by XR_RUNTIME_JSON. It hosts
 * unmodified applications (Khronos's hello_xr, `vrcorrect xr`, the tests' own applications): one
 * instance, one head-mounted system with a stereo view configuration, XR_KHR_opengl_enable
 * (Xlib/GLX binding: textures made in the application's current GL context), XR_KHR_vulkan_enable
 * and XR_KHR_vulkan_enable2 (images made on the application's VkDevice, in
 * COLOR_ATTACHMENT_OPTIMAL between acquire and release, as the extensions require), the
 * enumerations applications query (view configurations, blend modes, reference spaces, swapchain
 * formats: float and 10-bit first, as Monado offers them), reference spaces (VIEW, LOCAL, STAGE)
 * and their locations, the action system (action sets, actions, paths, suggested bindings, attach,
 * sync, states, action spaces; no controller is ever connected: every action is inactive and every
 * action space unlocated; haptics are no-ops; with XRTEST_GAZE_DEG, a simulated eye tracker,
 * XR_EXT_eye_gaze_interaction, is the one input that can be live), the event queue with the session
 * state machine, and the frame loop. At xrEndFrame it reads each projection view's submitted image
 * back (GL: glGetTexImage; Vulkan: a copy to a host-visible buffer on the application's queue, waited for)
 * and writes it as a .npy file.
 *
 * Types come from the Khronos headers (Debian libopenxr-dev, libvulkan-dev, libgl-dev, libx11-dev);
 * the loader negotiation structures, which those headers do not declare, are declared here from the
 * loader specification. GL is reached through libGL.so.1 and Vulkan through libvulkan.so.1, both
 * opened at run time (no link-time dependency): `cc -shared -fPIC xr_test_runtime.c -ldl -lm`.
 *
 * Environment (all optional):
 *   XRTEST_OUT_DIR         write runtime.log and the frames there (the folder is made when missing):
 *                          runtime.log: one line per call that creates, destroys or changes state
 *                          (instance, session, swapchains, spaces, actions, graphics devices), per
 *                          state change and per xrEndFrame ("end_frame N layers=L views=S:x,y,wxh ..."),
 *                          not for the per-frame queries (wait, begin, locate, sync, action states);
 *                          frame_NNNNN_view_V.npy: view V's submitted imageRect, top row first, as
 *                          uint8 (H, W, 4) RGBA for 8-bit formats (sRGB formats: the stored codes;
 *                          BGRA formats reordered to RGBA), uint32 (H, W) packed R | G << 10 | B << 20 |
 *                          A << 30 for the 10-bit formats, float16 (H, W, 4) for the half-float ones
 *   XRTEST_DUMP_SWAPCHAINS "1": at every xrEndFrame also write frame_NNNNN_swapchain_S.npy, the whole last
 *                          released image of every swapchain S (numbered as in "create_swapchain S")
 *   XRTEST_VIEW_SIZE       recommended size of each view, WxH (default 256x256)
 *   XRTEST_FORMATS         swapchain formats offered, in order (default
 *                          "rgba16f,rgb10a2,srgb,bgra8srgb,rgba8,bgra8"; names the session's API lacks are
 *                          skipped): rgba16f (GL_RGBA16F, R16G16B16A16_SFLOAT), rgb10a2 (GL_RGB10_A2,
 *                          A2B10G10R10_UNORM_PACK32), srgb (GL_SRGB8_ALPHA8, R8G8B8A8_SRGB), bgra8srgb
 *                          (B8G8R8A8_SRGB), rgba8 (GL_RGBA8, R8G8B8A8_UNORM), bgra8 (B8G8R8A8_UNORM), and,
 *                          offered only when named, rgba16 (GL_RGBA16, R16G16B16A16_UNORM; dumped as uint16
 *                          (H, W, 4))
 *   XRTEST_FRAME_MS        pace xrWaitFrame to this period, as a compositor does (default: no pacing,
 *                          a predicted period of 11.1 ms)
 *   XRTEST_LOSS_AFTER      after this many xrEndFrame calls the session goes LOSS_PENDING
 *   XRTEST_STOP_AFTER      after this many xrEndFrame calls the runtime asks the app to quit
 *                          (FOCUSED -> VISIBLE -> SYNCHRONIZED -> STOPPING, then IDLE -> EXITING)
 *   XRTEST_STOP_FILE       the same, at the first xrEndFrame after this file exists
 *                          (with XRTEST_OUT_DIR, frame_times.txt records every xrEndFrame that reaches the
 *                          runtime: when it arrived, the gap since the previous one, the time from
 *                          xrBeginFrame to it, which holds the application's rendering and every API layer's
 *                          time in xrEndFrame, and the runtime's own time in it)
 *   XRTEST_YAW_MRAD        the head turns left about the vertical axis through its centre by this many
 *                          milliradians per xrEndFrame call (default 0: a still head)
 *   XRTEST_NO_HMD          "1": xrGetSystem answers XR_ERROR_FORM_FACTOR_UNAVAILABLE
 *   XRTEST_GAZE_DEG        a simulated eye tracker: the gaze path "x,y;x,y;...", at most 4096 points, x to the
 *                          right and y up in degrees (|x|, |y| <= 80) from the head's forward direction (-z of
 *                          VIEW); point i is the gaze while i xrEndFrame calls have completed (the frame written
 *                          as frame_i), the last point holds after the end. Only with it is
 *                          XR_EXT_eye_gaze_interaction offered: /interaction_profiles/ext/eye_gaze_interaction
 *                          takes /user/eyes_ext/input/gaze_ext/pose bindings of pose actions; such an action is
 *                          active, and its action spaces located, after an xrSyncActions in FOCUSED that named
 *                          its set: the head's pose turned so that -z points along normalize(tan x, tan y, -1)
 *                          in VIEW (yaw about +y, then pitch about the new +x), at the head's centre. Malformed
 *                          (an empty value too): the extension is not offered (so the loader refuses it) and
 *                          xrCreateInstance fails with XR_ERROR_INITIALIZATION_FAILED and one line in runtime.log
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <math.h>
#include <stdarg.h>
#include <stddef.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>
#include <sys/stat.h>

#include <X11/Xlib.h>
#include <GL/glx.h>
#include <vulkan/vulkan.h>
#define XR_USE_PLATFORM_XLIB
#define XR_USE_GRAPHICS_API_OPENGL
#define XR_USE_GRAPHICS_API_VULKAN
#include <openxr/openxr.h>
#include <openxr/openxr_platform.h>

#define EXPORT __attribute__((visibility("default")))

/* ------------------------------------------------------------------ loader negotiation (loader spec) */
typedef struct {
    int32_t structType; uint32_t structVersion; size_t structSize;
    uint32_t minInterfaceVersion, maxInterfaceVersion;
    XrVersion minApiVersion, maxApiVersion;
} NegotiateLoaderInfo;
typedef struct {
    int32_t structType; uint32_t structVersion; size_t structSize;
    uint32_t runtimeInterfaceVersion; XrVersion runtimeApiVersion;
    PFN_xrGetInstanceProcAddr getInstanceProcAddr;
} NegotiateRuntimeRequest;

/* ------------------------------------------------------------------ constants */
#define L_GL_SRGB8_ALPHA8 0x8C43
#define L_GL_RGBA8 0x8058
#define L_GL_RGB10_A2 0x8059
#define L_GL_RGBA16F 0x881A
#define L_GL_RGBA16 0x805B
#define L_GL_HALF_FLOAT 0x140B
#define L_GL_UNSIGNED_INT_2_10_10_10_REV 0x8368
#define L_GL_PIXEL_PACK_BUFFER 0x88EB
#define L_GL_PIXEL_PACK_BUFFER_BINDING 0x88ED
#define L_GL_TEXTURE_MAX_LEVEL 0x813D

#define INSTANCE_ID 0x1001
#define SESSION_ID 0x2001
#define SPACE_BASE 0x3000
#define SWAPCHAIN_BASE 0x4000
#define ACTION_SET_BASE 0x5000
#define ACTION_BASE 0x6000
#define SYSTEM_ID 7
#define MAX_SWAPCHAINS 16
#define IMAGES 3
#define MAX_SPACES 32
#define MAX_PATHS 256
#define MAX_ACTION_SETS 8
#define MAX_ACTIONS 64
#define QUEUE 64
#define H(type, id) ((type)(uintptr_t)(id))
#define ID(handle) ((uintptr_t)(handle))

enum { API_NONE, API_GL, API_VULKAN };
/* how a format is read back and written: 8-bit RGBA, 8-bit BGRA (reordered), packed 10-bit, half float,
 * 16-bit unsigned normalized */
enum { K_RGBA8, K_BGRA8, K_PACKED10, K_HALF, K_U16 };
static const struct { const char *name; int64_t gl; int64_t vk; int kind; } FORMATS[] = {
    {"rgba16f", L_GL_RGBA16F, VK_FORMAT_R16G16B16A16_SFLOAT, K_HALF},
    {"rgb10a2", L_GL_RGB10_A2, VK_FORMAT_A2B10G10R10_UNORM_PACK32, K_PACKED10},
    {"srgb", L_GL_SRGB8_ALPHA8, VK_FORMAT_R8G8B8A8_SRGB, K_RGBA8},
    {"bgra8srgb", 0, VK_FORMAT_B8G8R8A8_SRGB, K_BGRA8},
    {"rgba8", L_GL_RGBA8, VK_FORMAT_R8G8B8A8_UNORM, K_RGBA8},
    {"bgra8", 0, VK_FORMAT_B8G8R8A8_UNORM, K_BGRA8},
    {"rgba16", L_GL_RGBA16, VK_FORMAT_R16G16B16A16_UNORM, K_U16},
};
#define NFORMATS (int)(sizeof FORMATS / sizeof FORMATS[0])
static const char *DEFAULT_FORMATS = "rgba16f,rgb10a2,srgb,bgra8srgb,rgba8,bgra8";
static const char *STATE_NAMES[] = {"UNKNOWN", "IDLE", "READY", "SYNCHRONIZED", "VISIBLE", "FOCUSED",
                                    "STOPPING", "LOSS_PENDING", "EXITING"};
/* the extensions: XR_EXT_eye_gaze_interaction is offered only with a valid XRTEST_GAZE_DEG (gaze_configured) */
enum { EXT_GL, EXT_VK1, EXT_VK2, EXT_EYE_GAZE, NEXTENSIONS };
static const struct { const char *name; uint32_t version; } EXTENSIONS[NEXTENSIONS] = {
    [EXT_GL] = {XR_KHR_OPENGL_ENABLE_EXTENSION_NAME, XR_KHR_opengl_enable_SPEC_VERSION},
    [EXT_VK1] = {XR_KHR_VULKAN_ENABLE_EXTENSION_NAME, XR_KHR_vulkan_enable_SPEC_VERSION},
    [EXT_VK2] = {XR_KHR_VULKAN_ENABLE2_EXTENSION_NAME, XR_KHR_vulkan_enable2_SPEC_VERSION},
    [EXT_EYE_GAZE] = {XR_EXT_EYE_GAZE_INTERACTION_EXTENSION_NAME, XR_EXT_eye_gaze_interaction_SPEC_VERSION},
};
/* XR_EXT_eye_gaze_interaction's paths */
#define EYE_GAZE_PROFILE "/interaction_profiles/ext/eye_gaze_interaction"
#define EYE_GAZE_USER "/user/eyes_ext"
#define EYE_GAZE_POSE "/user/eyes_ext/input/gaze_ext/pose"
#define MAX_GAZE_POINTS 4096
static const XrDuration DEFAULT_PERIOD_NS = 11111111; /* 90 Hz */

/* ------------------------------------------------------------------ GL through libGL.so.1 */
static struct {
    GLXContext (*GetCurrentContext)(void);
    void (*GetIntegerv)(GLenum, GLint *);
    void (*GenTextures)(GLsizei, GLuint *);
    void (*DeleteTextures)(GLsizei, const GLuint *);
    void (*BindTexture)(GLenum, GLuint);
    void (*TexImage2D)(GLenum, GLint, GLint, GLsizei, GLsizei, GLint, GLenum, GLenum, const void *);
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

/* ------------------------------------------------------------------ Vulkan through libvulkan.so.1 */
static struct {
    PFN_vkGetInstanceProcAddr GetInstanceProcAddr;
    PFN_vkEnumeratePhysicalDevices EnumeratePhysicalDevices;
    PFN_vkGetPhysicalDeviceMemoryProperties GetPhysicalDeviceMemoryProperties;
    PFN_vkGetDeviceProcAddr GetDeviceProcAddr;
    PFN_vkGetDeviceQueue GetDeviceQueue;
    PFN_vkCreateImage CreateImage;
    PFN_vkDestroyImage DestroyImage;
    PFN_vkGetImageMemoryRequirements GetImageMemoryRequirements;
    PFN_vkAllocateMemory AllocateMemory;
    PFN_vkFreeMemory FreeMemory;
    PFN_vkBindImageMemory BindImageMemory;
    PFN_vkCreateBuffer CreateBuffer;
    PFN_vkDestroyBuffer DestroyBuffer;
    PFN_vkGetBufferMemoryRequirements GetBufferMemoryRequirements;
    PFN_vkBindBufferMemory BindBufferMemory;
    PFN_vkMapMemory MapMemory;
    PFN_vkUnmapMemory UnmapMemory;
    PFN_vkCreateCommandPool CreateCommandPool;
    PFN_vkDestroyCommandPool DestroyCommandPool;
    PFN_vkAllocateCommandBuffers AllocateCommandBuffers;
    PFN_vkResetCommandBuffer ResetCommandBuffer;
    PFN_vkBeginCommandBuffer BeginCommandBuffer;
    PFN_vkEndCommandBuffer EndCommandBuffer;
    PFN_vkCmdPipelineBarrier CmdPipelineBarrier;
    PFN_vkCmdCopyImageToBuffer CmdCopyImageToBuffer;
    PFN_vkQueueSubmit QueueSubmit;
    PFN_vkCreateFence CreateFence;
    PFN_vkDestroyFence DestroyFence;
    PFN_vkWaitForFences WaitForFences;
    PFN_vkResetFences ResetFences;
} vk;

static int load_vulkan_loader(void) {
    if (vk.GetInstanceProcAddr) return 1;
    void *lib = dlopen("libvulkan.so.1", RTLD_NOW | RTLD_GLOBAL);
    if (!lib) return 0;
    *(void **)&vk.GetInstanceProcAddr = dlsym(lib, "vkGetInstanceProcAddr");
    return vk.GetInstanceProcAddr != NULL;
}

static int load_vulkan_device(VkInstance instance, VkDevice device) {
    if (!load_vulkan_loader()) return 0;
#define IGET(field, name) *(void **)&vk.field = (void *)vk.GetInstanceProcAddr(instance, name); if (!vk.field) return 0;
    IGET(EnumeratePhysicalDevices, "vkEnumeratePhysicalDevices")
    IGET(GetPhysicalDeviceMemoryProperties, "vkGetPhysicalDeviceMemoryProperties")
    IGET(GetDeviceProcAddr, "vkGetDeviceProcAddr")
#undef IGET
#define DGET(field, name) *(void **)&vk.field = (void *)vk.GetDeviceProcAddr(device, name); if (!vk.field) return 0;
    DGET(GetDeviceQueue, "vkGetDeviceQueue") DGET(CreateImage, "vkCreateImage") DGET(DestroyImage, "vkDestroyImage")
    DGET(GetImageMemoryRequirements, "vkGetImageMemoryRequirements") DGET(AllocateMemory, "vkAllocateMemory")
    DGET(FreeMemory, "vkFreeMemory") DGET(BindImageMemory, "vkBindImageMemory") DGET(CreateBuffer, "vkCreateBuffer")
    DGET(DestroyBuffer, "vkDestroyBuffer") DGET(GetBufferMemoryRequirements, "vkGetBufferMemoryRequirements")
    DGET(BindBufferMemory, "vkBindBufferMemory") DGET(MapMemory, "vkMapMemory") DGET(UnmapMemory, "vkUnmapMemory")
    DGET(CreateCommandPool, "vkCreateCommandPool") DGET(DestroyCommandPool, "vkDestroyCommandPool")
    DGET(AllocateCommandBuffers, "vkAllocateCommandBuffers") DGET(ResetCommandBuffer, "vkResetCommandBuffer")
    DGET(BeginCommandBuffer, "vkBeginCommandBuffer") DGET(EndCommandBuffer, "vkEndCommandBuffer")
    DGET(CmdPipelineBarrier, "vkCmdPipelineBarrier") DGET(CmdCopyImageToBuffer, "vkCmdCopyImageToBuffer")
    DGET(QueueSubmit, "vkQueueSubmit") DGET(CreateFence, "vkCreateFence") DGET(DestroyFence, "vkDestroyFence")
    DGET(WaitForFences, "vkWaitForFences") DGET(ResetFences, "vkResetFences")
#undef DGET
    return 1;
}

/* ------------------------------------------------------------------ state */
typedef struct {
    int used, width, height, format_index, usage;
    int64_t format;
    GLuint tex[IMAGES];
    VkImage image[IMAGES];
    VkDeviceMemory memory[IMAGES];
    int next, acquired, waited, released_index;
} Swapchain;
typedef struct {                       /* a reference space (action < 0) or an action space */
    int used, type, action;
    XrPath subaction;
    XrPosef pose;
} Space;
typedef struct {
    int used, attached; char name[XR_MAX_ACTION_SET_NAME_SIZE];
    int synced;                        /* active for /user/eyes_ext in the latest xrSyncActions */
} ActionSet;
typedef struct {
    int used, set; XrActionType type; char name[XR_MAX_ACTION_NAME_SIZE];
    int gaze;                          /* bound to the gaze pose by the latest eye-gaze suggestion */
} Action;
typedef struct { XrEventDataBuffer buffer; } Event;

static struct {
    int instance, session, api, state, running, exit_requested, quit_after_stop;
    int enabled[NEXTENSIONS], gl_reqs, vk_reqs;
    int frame_waited, frame_begun, view_w, view_h, nformats, format_index[NFORMATS], dump_swapchains;
    long end_frames, loss_after, stop_after;
    double yaw_per_frame;
    XrDuration period;
    int paced;
    XrTime t0, next_display, last_wait;
    XrTime began, last_end;            /* the last xrBeginFrame's return, the last xrEndFrame's arrival */
    Swapchain sc[MAX_SWAPCHAINS];
    Space spaces[MAX_SPACES];
    char paths[MAX_PATHS][XR_MAX_PATH_LENGTH];
    int npaths;
    ActionSet sets[MAX_ACTION_SETS];
    Action actions[MAX_ACTIONS];
    int actions_attached;
    int synced_focused;                /* the latest xrSyncActions found the session FOCUSED */
    int ngaze;                         /* XRTEST_GAZE_DEG's points (0: no eye tracker) */
    double gaze_deg[MAX_GAZE_POINTS][2];
    Event queue[QUEUE];
    int qhead, qtail;
    char out_dir[1024], stop_file[1024];
    /* Vulkan: what the application gave or asked for */
    VkInstance vk_instance;            /* the instance xrGetVulkanGraphicsDevice(2)KHR was asked about */
    VkPhysicalDevice vk_physical;
    VkDevice vk_device;
    VkQueue vk_queue;
    uint32_t vk_family;
    VkCommandPool vk_pool;
    VkCommandBuffer vk_cmd;
    VkFence vk_fence;
    VkBuffer vk_buffer;
    VkDeviceMemory vk_buffer_memory;
    VkDeviceSize vk_buffer_size;
    void *vk_mapped;
} rt;

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

/* XRTEST_GAZE_DEG's text ("x,y;x,y;...") into points of (x, y) degrees, when out is not NULL: the number of
 * points, or -1 when the text is malformed (then *bad is the 1-based point where it went wrong) */
static int parse_gaze(const char *text, double (*out)[2], int *bad) {
    const char *p = text;
    for (int n = 0;; ) {
        double v[2];
        *bad = n + 1;
        for (int c = 0; c < 2; c++) {              /* a number, then ',' after x */
            char *end;
            v[c] = strtod(p, &end);
            if (end == p || !(fabs(v[c]) <= 80.0)) return -1;
            p = end + strspn(end, " \t");
            if (c == 0 && *p++ != ',') return -1;
        }
        if (n == MAX_GAZE_POINTS) return -1;
        if (out) out[n][0] = v[0], out[n][1] = v[1];
        n++;
        if (*p == 0) return n;
        if (*p++ != ';') return -1;
    }
}

/* XRTEST_GAZE_DEG is set and well formed */
static int gaze_configured(void) {
    const char *text = getenv("XRTEST_GAZE_DEG");
    int bad;
    return text && parse_gaze(text, NULL, &bad) > 0;
}

static void push_event(const void *event, size_t size) {
    Event *e = &rt.queue[rt.qtail % QUEUE];
    rt.qtail++;
    memset(e, 0, sizeof *e);
    memcpy(&e->buffer, event, size);
}

static void push_state(XrSessionState state) {
    rt.state = (int)state;
    logf_("state %s", STATE_NAMES[state]);
    XrEventDataSessionStateChanged e = {XR_TYPE_EVENT_DATA_SESSION_STATE_CHANGED, NULL, H(XrSession, SESSION_ID),
                                        state, now_ns()};
    push_event(&e, sizeof e);
}

/* the count-then-fill idiom of every xrEnumerate* call */
#define ENUMERATE(cap, count_out, n, ...) do { \
        if (!(count_out)) return XR_ERROR_VALIDATION_FAILURE; \
        *(count_out) = (uint32_t)(n); \
        if ((cap) == 0) return XR_SUCCESS; \
        if ((cap) < (uint32_t)(n)) return XR_ERROR_SIZE_INSUFFICIENT; \
        for (uint32_t i = 0; i < (uint32_t)(n); i++) { __VA_ARGS__; } \
        return XR_SUCCESS; } while (0)

/* a string output (count includes the terminating zero) */
static XrResult copy_string(const char *text, uint32_t cap, uint32_t *count, char *buffer) {
    if (!count) return XR_ERROR_VALIDATION_FAILURE;
    *count = (uint32_t)strlen(text) + 1;
    if (cap == 0) return XR_SUCCESS;
    if (cap < *count || !buffer) return XR_ERROR_SIZE_INSUFFICIENT;
    memcpy(buffer, text, *count);
    return XR_SUCCESS;
}

#define CHECK_INSTANCE(h) if (!rt.instance || ID(h) != INSTANCE_ID) return XR_ERROR_HANDLE_INVALID
#define CHECK_SESSION(h) if (!rt.session || ID(h) != SESSION_ID) return XR_ERROR_HANDLE_INVALID
#define CHECK_SYSTEM(id) if ((id) != SYSTEM_ID) return XR_ERROR_SYSTEM_INVALID

/* ------------------------------------------------------------------ poses */
static XrQuaternionf quat_mul(XrQuaternionf a, XrQuaternionf b) {
    return (XrQuaternionf){a.w * b.x + a.x * b.w + a.y * b.z - a.z * b.y, a.w * b.y - a.x * b.z + a.y * b.w + a.z * b.x,
                           a.w * b.z + a.x * b.y - a.y * b.x + a.z * b.w, a.w * b.w - a.x * b.x - a.y * b.y - a.z * b.z};
}

static XrVector3f rotate(XrQuaternionf q, XrVector3f v) {
    XrQuaternionf p = quat_mul(quat_mul(q, (XrQuaternionf){v.x, v.y, v.z, 0}), (XrQuaternionf){-q.x, -q.y, -q.z, q.w});
    return (XrVector3f){p.x, p.y, p.z};
}

/* a then b: the pose b (given in a's frame) in a's parent frame */
static XrPosef compose(XrPosef a, XrPosef b) {
    XrVector3f t = rotate(a.orientation, b.position);
    return (XrPosef){quat_mul(a.orientation, b.orientation),
                     {a.position.x + t.x, a.position.y + t.y, a.position.z + t.z}};
}

static XrPosef invert(XrPosef a) {
    XrQuaternionf q = {-a.orientation.x, -a.orientation.y, -a.orientation.z, a.orientation.w};
    XrVector3f t = rotate(q, a.position);
    return (XrPosef){q, {-t.x, -t.y, -t.z}};
}

static const XrPosef IDENTITY = {{0, 0, 0, 1}, {0, 0, 0}};

/* The head in LOCAL space: at LOCAL's origin, turned left (about +y) by yaw_per_frame for every frame
 * ended so far. STAGE's origin is on the floor 1.6 m below LOCAL's. */
static XrPosef head_pose(void) {
    double yaw = rt.yaw_per_frame * (double)rt.end_frames;
    return (XrPosef){{0, (float)sin(0.5 * yaw), 0, (float)cos(0.5 * yaw)}, {0, 0, 0}};
}

/* The eye tracker's gaze relative to the head, for the frame under way (XRTEST_GAZE_DEG's point
 * rt.end_frames, the last one after the end): a yaw about +y, then a pitch about the new +x, turning
 * -z to normalize(tan x, tan y, -1). */
static XrQuaternionf gaze_rotation(void) {
    const double *g = rt.gaze_deg[rt.end_frames < rt.ngaze ? rt.end_frames : rt.ngaze - 1];
    double tx = tan(g[0] * M_PI / 180.0), ty = tan(g[1] * M_PI / 180.0);
    double yaw = atan2(-tx, 1.0), pitch = atan2(ty, sqrt(tx * tx + 1.0));
    XrQuaternionf turn = {0, (float)sin(0.5 * yaw), 0, (float)cos(0.5 * yaw)};
    XrQuaternionf tilt = {(float)sin(0.5 * pitch), 0, 0, (float)cos(0.5 * pitch)};
    return quat_mul(turn, tilt);
}

static XrPosef reference_pose(XrReferenceSpaceType type) {
    if (type == XR_REFERENCE_SPACE_TYPE_VIEW) return head_pose();
    if (type == XR_REFERENCE_SPACE_TYPE_STAGE) return (XrPosef){{0, 0, 0, 1}, {0, -1.6f, 0}};
    return IDENTITY;
}

/* ------------------------------------------------------------------ instance and system */
static XrResult enumerate_instance_extension_properties(const char *layer, uint32_t cap, uint32_t *count,
                                                        XrExtensionProperties *props) {
    if (layer && *layer) return XR_ERROR_API_LAYER_NOT_PRESENT;
    int offered[NEXTENSIONS], n = 0;
    for (int k = 0; k < NEXTENSIONS; k++)
        if (k != EXT_EYE_GAZE || gaze_configured()) offered[n++] = k;
    ENUMERATE(cap, count, n, {
        snprintf(props[i].extensionName, XR_MAX_EXTENSION_NAME_SIZE, "%s", EXTENSIONS[offered[i]].name);
        props[i].extensionVersion = EXTENSIONS[offered[i]].version;
    });
}

/* XRTEST_FORMATS (or the default) into rt.format_index: indices into FORMATS, in order, unknown names skipped */
static void read_formats(void) {
    const char *formats = getenv("XRTEST_FORMATS");
    if (!formats) formats = DEFAULT_FORMATS;
    rt.nformats = 0;
    for (const char *p = formats; *p;) {
        p += strspn(p, " ,");
        size_t n = strcspn(p, " ,");
        for (int k = 0; k < NFORMATS && n; k++) {
            if (strlen(FORMATS[k].name) != n || strncmp(p, FORMATS[k].name, n) != 0) continue;
            int seen = 0;
            for (int i = 0; i < rt.nformats; i++) seen |= rt.format_index[i] == k;
            if (!seen) rt.format_index[rt.nformats++] = k;
        }
        p += n;
    }
}

static XrResult create_instance(const XrInstanceCreateInfo *info, XrInstance *instance) {
    if (!info || !instance) return XR_ERROR_VALIDATION_FAILURE;
    if (rt.instance) return XR_ERROR_LIMIT_REACHED;
    XrVersion v = info->applicationInfo.apiVersion;
    if (XR_VERSION_MAJOR(v) != 1 || XR_VERSION_MINOR(v) > 1) return XR_ERROR_API_VERSION_UNSUPPORTED;
    memset(&rt, 0, sizeof rt);
    const char *out = getenv("XRTEST_OUT_DIR");
    if (out) {                                   /* made, with its parents, when missing */
        snprintf(rt.out_dir, sizeof rt.out_dir, "%s", out);
        char dir[sizeof rt.out_dir];
        snprintf(dir, sizeof dir, "%s", out);
        for (char *p = dir + 1; *p; p++)
            if (*p == '/') { *p = 0; mkdir(dir, 0755); *p = '/'; }
        mkdir(dir, 0755);
    }
    const char *gaze = getenv("XRTEST_GAZE_DEG");   /* malformed: refused whatever the application enables */
    int bad = 0;
    if (gaze && (rt.ngaze = parse_gaze(gaze, rt.gaze_deg, &bad)) < 0) {
        logf_("XRTEST_GAZE_DEG=\"%s\" is malformed at point %d: expected \"x,y;x,y;...\" (the gaze in degrees, "
              "x right, y up, |x| and |y| at most 80; at most %d points)", gaze, bad, MAX_GAZE_POINTS);
        rt.ngaze = 0;
        return XR_ERROR_INITIALIZATION_FAILED;
    }
    for (uint32_t i = 0; i < info->enabledExtensionCount; i++) {
        int found = 0;
        for (int k = 0; k < NEXTENSIONS; k++)
            if (strcmp(info->enabledExtensionNames[i], EXTENSIONS[k].name) == 0 && (k != EXT_EYE_GAZE || rt.ngaze > 0))
                found = rt.enabled[k] = 1;
        if (!found) return XR_ERROR_EXTENSION_NOT_PRESENT;
    }
    const char *stop = getenv("XRTEST_STOP_FILE");
    if (stop) snprintf(rt.stop_file, sizeof rt.stop_file, "%s", stop);
    rt.view_w = rt.view_h = 256;
    const char *size = getenv("XRTEST_VIEW_SIZE");
    if (size && (sscanf(size, "%dx%d", &rt.view_w, &rt.view_h) != 2 || rt.view_w < 1 || rt.view_h < 1))
        return XR_ERROR_RUNTIME_FAILURE;
    read_formats();
    rt.loss_after = env_long("XRTEST_LOSS_AFTER", 0);
    rt.stop_after = env_long("XRTEST_STOP_AFTER", 0);
    rt.yaw_per_frame = 1e-3 * (double)env_long("XRTEST_YAW_MRAD", 0);
    rt.dump_swapchains = env_long("XRTEST_DUMP_SWAPCHAINS", 0) != 0;
    long frame_ms = env_long("XRTEST_FRAME_MS", 0);
    rt.paced = frame_ms > 0;
    rt.period = rt.paced ? (XrDuration)frame_ms * 1000000 : DEFAULT_PERIOD_NS;
    rt.instance = 1;
    *instance = H(XrInstance, INSTANCE_ID);
    logf_("create_instance app=%s api=%u.%u ext=%u", info->applicationInfo.applicationName, XR_VERSION_MAJOR(v),
          XR_VERSION_MINOR(v), info->enabledExtensionCount);
    if (rt.ngaze)
        logf_("gaze path %d points%s", rt.ngaze,
              rt.enabled[EXT_EYE_GAZE] ? "" : " (XR_EXT_eye_gaze_interaction not enabled)");
    return XR_SUCCESS;
}

static XrResult destroy_instance(XrInstance instance) {
    CHECK_INSTANCE(instance);
    logf_("destroy_instance");
    rt.instance = 0;
    return XR_SUCCESS;
}

static XrResult get_instance_properties(XrInstance instance, XrInstanceProperties *p) {
    CHECK_INSTANCE(instance);
    p->runtimeVersion = XR_MAKE_VERSION(0, 2, 0);
    snprintf(p->runtimeName, sizeof p->runtimeName, "vrcorrect test runtime");
    return XR_SUCCESS;
}

static XrResult result_to_string(XrInstance instance, XrResult value, char buffer[XR_MAX_RESULT_STRING_SIZE]) {
    (void)instance;
    snprintf(buffer, XR_MAX_RESULT_STRING_SIZE, value == 0 ? "XR_SUCCESS" : "XR_RESULT_%d", value);
    return XR_SUCCESS;
}

static XrResult structure_type_to_string(XrInstance instance, XrStructureType value,
                                         char buffer[XR_MAX_STRUCTURE_NAME_SIZE]) {
    (void)instance;
    snprintf(buffer, XR_MAX_STRUCTURE_NAME_SIZE, "XR_STRUCTURE_TYPE_%d", (int)value);
    return XR_SUCCESS;
}

static XrResult get_system(XrInstance instance, const XrSystemGetInfo *info, XrSystemId *id) {
    CHECK_INSTANCE(instance);
    if (info->formFactor != XR_FORM_FACTOR_HEAD_MOUNTED_DISPLAY) return XR_ERROR_FORM_FACTOR_UNSUPPORTED;
    if (env_long("XRTEST_NO_HMD", 0)) return XR_ERROR_FORM_FACTOR_UNAVAILABLE;
    *id = SYSTEM_ID;
    return XR_SUCCESS;
}

static XrResult get_system_properties(XrInstance instance, XrSystemId id, XrSystemProperties *p) {
    CHECK_INSTANCE(instance);
    CHECK_SYSTEM(id);
    p->systemId = id;
    p->vendorId = 0;
    snprintf(p->systemName, sizeof p->systemName, "vrcorrect test headset");
    p->graphicsProperties.maxSwapchainImageWidth = p->graphicsProperties.maxSwapchainImageHeight = 4096;
    p->graphicsProperties.maxLayerCount = 16;
    p->trackingProperties.orientationTracking = p->trackingProperties.positionTracking = XR_TRUE;
    for (XrBaseOutStructure *n = (XrBaseOutStructure *)p->next; n; n = n->next)
        if (n->type == XR_TYPE_SYSTEM_EYE_GAZE_INTERACTION_PROPERTIES_EXT)
            ((XrSystemEyeGazeInteractionPropertiesEXT *)n)->supportsEyeGazeInteraction =
                rt.enabled[EXT_EYE_GAZE] ? XR_TRUE : XR_FALSE;
    return XR_SUCCESS;
}

static XrResult enumerate_view_configurations(XrInstance instance, XrSystemId id, uint32_t cap, uint32_t *count,
                                              XrViewConfigurationType *types) {
    CHECK_INSTANCE(instance);
    CHECK_SYSTEM(id);
    ENUMERATE(cap, count, 1, types[i] = XR_VIEW_CONFIGURATION_TYPE_PRIMARY_STEREO);
}

static XrResult get_view_configuration_properties(XrInstance instance, XrSystemId id, XrViewConfigurationType type,
                                                  XrViewConfigurationProperties *p) {
    CHECK_INSTANCE(instance);
    CHECK_SYSTEM(id);
    if (type != XR_VIEW_CONFIGURATION_TYPE_PRIMARY_STEREO) return XR_ERROR_VIEW_CONFIGURATION_TYPE_UNSUPPORTED;
    p->viewConfigurationType = type;
    p->fovMutable = XR_FALSE;
    return XR_SUCCESS;
}

static XrResult enumerate_view_configuration_views(XrInstance instance, XrSystemId id, XrViewConfigurationType type,
                                                   uint32_t cap, uint32_t *count, XrViewConfigurationView *views) {
    CHECK_INSTANCE(instance);
    CHECK_SYSTEM(id);
    if (type != XR_VIEW_CONFIGURATION_TYPE_PRIMARY_STEREO) return XR_ERROR_VIEW_CONFIGURATION_TYPE_UNSUPPORTED;
    ENUMERATE(cap, count, 2, {
        views[i].recommendedImageRectWidth = (uint32_t)rt.view_w;
        views[i].recommendedImageRectHeight = (uint32_t)rt.view_h;
        views[i].maxImageRectWidth = views[i].maxImageRectHeight = 4096;
        views[i].recommendedSwapchainSampleCount = views[i].maxSwapchainSampleCount = 1;
    });
}

static XrResult enumerate_environment_blend_modes(XrInstance instance, XrSystemId id, XrViewConfigurationType type,
                                                  uint32_t cap, uint32_t *count, XrEnvironmentBlendMode *modes) {
    CHECK_INSTANCE(instance);
    CHECK_SYSTEM(id);
    if (type != XR_VIEW_CONFIGURATION_TYPE_PRIMARY_STEREO) return XR_ERROR_VIEW_CONFIGURATION_TYPE_UNSUPPORTED;
    ENUMERATE(cap, count, 1, modes[i] = XR_ENVIRONMENT_BLEND_MODE_OPAQUE);
}

/* ------------------------------------------------------------------ graphics requirements and devices */
static XrResult get_opengl_graphics_requirements(XrInstance instance, XrSystemId id,
                                                 XrGraphicsRequirementsOpenGLKHR *r) {
    CHECK_INSTANCE(instance);
    CHECK_SYSTEM(id);
    r->minApiVersionSupported = XR_MAKE_VERSION(3, 3, 0);
    r->maxApiVersionSupported = XR_MAKE_VERSION(4, 6, 0);
    rt.gl_reqs = 1;
    logf_("graphics_requirements");
    return XR_SUCCESS;
}

static XrResult get_vulkan_graphics_requirements(XrInstance instance, XrSystemId id,
                                                 XrGraphicsRequirementsVulkanKHR *r) {
    CHECK_INSTANCE(instance);
    CHECK_SYSTEM(id);
    r->minApiVersionSupported = XR_MAKE_VERSION(1, 0, 0);
    r->maxApiVersionSupported = XR_MAKE_VERSION(1, 3, 0);
    rt.vk_reqs = 1;
    logf_("graphics_requirements vulkan");
    return XR_SUCCESS;
}

/* The runtime needs no Vulkan extension of its own: an empty list (a string of one zero byte). */
static XrResult get_vulkan_instance_extensions(XrInstance instance, XrSystemId id, uint32_t cap, uint32_t *count,
                                               char *buffer) {
    CHECK_INSTANCE(instance);
    CHECK_SYSTEM(id);
    return copy_string("", cap, count, buffer);
}

static XrResult get_vulkan_device_extensions(XrInstance instance, XrSystemId id, uint32_t cap, uint32_t *count,
                                             char *buffer) {
    CHECK_INSTANCE(instance);
    CHECK_SYSTEM(id);
    return copy_string("", cap, count, buffer);
}

/* the first physical device of the application's VkInstance (Mesa's lavapipe here) */
static XrResult get_vulkan_graphics_device(XrInstance instance, XrSystemId id, VkInstance vulkan,
                                          VkPhysicalDevice *physical) {
    CHECK_INSTANCE(instance);
    CHECK_SYSTEM(id);
    if (!vulkan || !physical) return XR_ERROR_VALIDATION_FAILURE;
    if (!load_vulkan_loader()) return XR_ERROR_RUNTIME_FAILURE;
    PFN_vkEnumeratePhysicalDevices enumerate =
        (PFN_vkEnumeratePhysicalDevices)vk.GetInstanceProcAddr(vulkan, "vkEnumeratePhysicalDevices");
    uint32_t n = 1;
    VkPhysicalDevice first = VK_NULL_HANDLE;
    VkResult r = enumerate ? enumerate(vulkan, &n, &first) : VK_ERROR_INITIALIZATION_FAILED;
    if ((r != VK_SUCCESS && r != VK_INCOMPLETE) || n < 1 || !first) return XR_ERROR_RUNTIME_FAILURE;
    rt.vk_instance = vulkan;
    rt.vk_physical = *physical = first;
    logf_("vulkan_graphics_device");
    return XR_SUCCESS;
}

static XrResult get_vulkan_graphics_device2(XrInstance instance, const XrVulkanGraphicsDeviceGetInfoKHR *info,
                                           VkPhysicalDevice *physical) {
    if (!info || info->type != XR_TYPE_VULKAN_GRAPHICS_DEVICE_GET_INFO_KHR) return XR_ERROR_VALIDATION_FAILURE;
    return get_vulkan_graphics_device(instance, info->systemId, info->vulkanInstance, physical);
}

static XrResult create_vulkan_instance(XrInstance instance, const XrVulkanInstanceCreateInfoKHR *info,
                                       VkInstance *vulkan, VkResult *result) {
    CHECK_INSTANCE(instance);
    if (!info || info->type != XR_TYPE_VULKAN_INSTANCE_CREATE_INFO_KHR || !info->pfnGetInstanceProcAddr ||
        !info->vulkanCreateInfo || !vulkan || !result)
        return XR_ERROR_VALIDATION_FAILURE;
    CHECK_SYSTEM(info->systemId);
    PFN_vkCreateInstance create = (PFN_vkCreateInstance)info->pfnGetInstanceProcAddr(NULL, "vkCreateInstance");
    if (!create) return XR_ERROR_RUNTIME_FAILURE;
    *result = create(info->vulkanCreateInfo, info->vulkanAllocator, vulkan);
    logf_("create_vulkan_instance %d", (int)*result);
    return XR_SUCCESS;
}

static XrResult create_vulkan_device(XrInstance instance, const XrVulkanDeviceCreateInfoKHR *info, VkDevice *device,
                                     VkResult *result) {
    CHECK_INSTANCE(instance);
    if (!info || info->type != XR_TYPE_VULKAN_DEVICE_CREATE_INFO_KHR || !info->pfnGetInstanceProcAddr ||
        !info->vulkanCreateInfo || !device || !result)
        return XR_ERROR_VALIDATION_FAILURE;
    CHECK_SYSTEM(info->systemId);
    if (!rt.vk_physical || info->vulkanPhysicalDevice != rt.vk_physical) return XR_ERROR_VALIDATION_FAILURE;
    PFN_vkCreateDevice create = (PFN_vkCreateDevice)info->pfnGetInstanceProcAddr(rt.vk_instance, "vkCreateDevice");
    if (!create) return XR_ERROR_RUNTIME_FAILURE;
    *result = create(info->vulkanPhysicalDevice, info->vulkanCreateInfo, info->vulkanAllocator, device);
    logf_("create_vulkan_device %d extensions=%u", (int)*result, info->vulkanCreateInfo->enabledExtensionCount);
    return XR_SUCCESS;
}

/* ------------------------------------------------------------------ Vulkan plumbing of the session */
static int vk_memory_type(uint32_t bits, VkMemoryPropertyFlags want) {
    VkPhysicalDeviceMemoryProperties props;
    vk.GetPhysicalDeviceMemoryProperties(rt.vk_physical, &props);
    for (uint32_t i = 0; i < props.memoryTypeCount; i++)
        if ((bits >> i & 1) && (props.memoryTypes[i].propertyFlags & want) == want) return (int)i;
    return -1;
}

static VkCommandBuffer vk_begin(void) {
    vk.ResetFences(rt.vk_device, 1, &rt.vk_fence);
    vk.ResetCommandBuffer(rt.vk_cmd, 0);
    VkCommandBufferBeginInfo begin = {VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO, NULL,
                                      VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT, NULL};
    vk.BeginCommandBuffer(rt.vk_cmd, &begin);
    return rt.vk_cmd;
}

static int vk_submit_and_wait(void) {
    vk.EndCommandBuffer(rt.vk_cmd);
    VkSubmitInfo submit = {VK_STRUCTURE_TYPE_SUBMIT_INFO, NULL, 0, NULL, NULL, 1, &rt.vk_cmd, 0, NULL};
    if (vk.QueueSubmit(rt.vk_queue, 1, &submit, rt.vk_fence) != VK_SUCCESS) return 0;
    return vk.WaitForFences(rt.vk_device, 1, &rt.vk_fence, VK_TRUE, UINT64_MAX) == VK_SUCCESS;
}

static void vk_barrier(VkCommandBuffer cmd, VkImage image, VkImageLayout from, VkImageLayout to,
                       VkAccessFlags src_access, VkAccessFlags dst_access) {
    VkImageMemoryBarrier b = {VK_STRUCTURE_TYPE_IMAGE_MEMORY_BARRIER, NULL, src_access, dst_access, from, to,
                              VK_QUEUE_FAMILY_IGNORED, VK_QUEUE_FAMILY_IGNORED, image,
                              {VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, 1}};
    vk.CmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, 0, 0, NULL, 0,
                          NULL, 1, &b);
}

static int vk_session_start(const XrGraphicsBindingVulkanKHR *b) {
    if (!load_vulkan_device(b->instance, b->device)) return 0;
    rt.vk_device = b->device;
    rt.vk_family = b->queueFamilyIndex;
    vk.GetDeviceQueue(b->device, b->queueFamilyIndex, b->queueIndex, &rt.vk_queue);
    VkCommandPoolCreateInfo pool = {VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO, NULL,
                                    VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT, b->queueFamilyIndex};
    if (!rt.vk_queue || vk.CreateCommandPool(b->device, &pool, NULL, &rt.vk_pool) != VK_SUCCESS) return 0;
    VkCommandBufferAllocateInfo alloc = {VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO, NULL, rt.vk_pool,
                                         VK_COMMAND_BUFFER_LEVEL_PRIMARY, 1};
    VkFenceCreateInfo fence = {VK_STRUCTURE_TYPE_FENCE_CREATE_INFO, NULL, 0};
    return vk.AllocateCommandBuffers(b->device, &alloc, &rt.vk_cmd) == VK_SUCCESS &&
           vk.CreateFence(b->device, &fence, NULL, &rt.vk_fence) == VK_SUCCESS;
}

static void vk_session_stop(void) {
    if (!rt.vk_device) return;
    if (rt.vk_mapped) vk.UnmapMemory(rt.vk_device, rt.vk_buffer_memory);
    if (rt.vk_buffer) vk.DestroyBuffer(rt.vk_device, rt.vk_buffer, NULL);
    if (rt.vk_buffer_memory) vk.FreeMemory(rt.vk_device, rt.vk_buffer_memory, NULL);
    if (rt.vk_fence) vk.DestroyFence(rt.vk_device, rt.vk_fence, NULL);
    if (rt.vk_pool) vk.DestroyCommandPool(rt.vk_device, rt.vk_pool, NULL);
    rt.vk_mapped = NULL;
    rt.vk_buffer = VK_NULL_HANDLE;
    rt.vk_buffer_memory = VK_NULL_HANDLE;
    rt.vk_buffer_size = 0;
    rt.vk_fence = VK_NULL_HANDLE;
    rt.vk_pool = VK_NULL_HANDLE;
    rt.vk_device = VK_NULL_HANDLE;
}

/* the host-visible read-back buffer, at least `size` bytes */
static int vk_readback_buffer(VkDeviceSize size) {
    if (rt.vk_buffer_size >= size) return 1;
    if (rt.vk_mapped) vk.UnmapMemory(rt.vk_device, rt.vk_buffer_memory);
    if (rt.vk_buffer) vk.DestroyBuffer(rt.vk_device, rt.vk_buffer, NULL);
    if (rt.vk_buffer_memory) vk.FreeMemory(rt.vk_device, rt.vk_buffer_memory, NULL);
    rt.vk_mapped = NULL;
    rt.vk_buffer_size = 0;
    VkBufferCreateInfo info = {VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO, NULL, 0, size, VK_BUFFER_USAGE_TRANSFER_DST_BIT,
                               VK_SHARING_MODE_EXCLUSIVE, 0, NULL};
    if (vk.CreateBuffer(rt.vk_device, &info, NULL, &rt.vk_buffer) != VK_SUCCESS) return 0;
    VkMemoryRequirements req;
    vk.GetBufferMemoryRequirements(rt.vk_device, rt.vk_buffer, &req);
    int type = vk_memory_type(req.memoryTypeBits,
                              VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT);
    VkMemoryAllocateInfo alloc = {VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO, NULL, req.size, (uint32_t)type};
    if (type < 0 || vk.AllocateMemory(rt.vk_device, &alloc, NULL, &rt.vk_buffer_memory) != VK_SUCCESS) return 0;
    if (vk.BindBufferMemory(rt.vk_device, rt.vk_buffer, rt.vk_buffer_memory, 0) != VK_SUCCESS ||
        vk.MapMemory(rt.vk_device, rt.vk_buffer_memory, 0, VK_WHOLE_SIZE, 0, &rt.vk_mapped) != VK_SUCCESS)
        return 0;
    rt.vk_buffer_size = size;
    return 1;
}

/* ------------------------------------------------------------------ session */
static XrResult create_session(XrInstance instance, const XrSessionCreateInfo *info, XrSession *session) {
    CHECK_INSTANCE(instance);
    CHECK_SYSTEM(info->systemId);
    if (rt.session) return XR_ERROR_LIMIT_REACHED;
    const XrGraphicsBindingOpenGLXlibKHR *glx = NULL;
    const XrGraphicsBindingVulkanKHR *vulkan = NULL;
    for (const XrBaseInStructure *b = info->next; b; b = b->next) {
        if (b->type == XR_TYPE_GRAPHICS_BINDING_OPENGL_XLIB_KHR) glx = (const XrGraphicsBindingOpenGLXlibKHR *)b;
        if (b->type == XR_TYPE_GRAPHICS_BINDING_VULKAN_KHR) vulkan = (const XrGraphicsBindingVulkanKHR *)b;
    }
    if (glx) {
        if (!rt.enabled[EXT_GL]) return XR_ERROR_VALIDATION_FAILURE;
        if (!rt.gl_reqs) return XR_ERROR_GRAPHICS_REQUIREMENTS_CALL_MISSING;
        if (!glx->xDisplay || !glx->glxContext || !glx->glxDrawable) return XR_ERROR_GRAPHICS_DEVICE_INVALID;
        if (!load_gl()) return XR_ERROR_RUNTIME_FAILURE;
        if (gl.GetCurrentContext() != glx->glxContext) {
            logf_("create_session: the binding's GLX context is not current");
            return XR_ERROR_GRAPHICS_DEVICE_INVALID;
        }
        rt.api = API_GL;
    } else if (vulkan) {
        if (!rt.enabled[EXT_VK1] && !rt.enabled[EXT_VK2]) return XR_ERROR_VALIDATION_FAILURE;
        if (!rt.vk_reqs) return XR_ERROR_GRAPHICS_REQUIREMENTS_CALL_MISSING;
        if (!vulkan->instance || !vulkan->device || !vulkan->physicalDevice ||
            vulkan->physicalDevice != rt.vk_physical) {
            logf_("create_session: the Vulkan binding does not name the physical device the runtime gave");
            return XR_ERROR_GRAPHICS_DEVICE_INVALID;
        }
        if (!vk_session_start(vulkan)) {
            vk_session_stop();
            return XR_ERROR_RUNTIME_FAILURE;
        }
        rt.api = API_VULKAN;
    } else {
        return XR_ERROR_GRAPHICS_DEVICE_INVALID;
    }
    rt.session = 1;
    rt.t0 = now_ns();
    *session = H(XrSession, SESSION_ID);
    logf_(rt.api == API_VULKAN ? "create_session vulkan" : "create_session");
    push_state(XR_SESSION_STATE_IDLE);
    push_state(XR_SESSION_STATE_READY);
    return XR_SUCCESS;
}

static XrResult destroy_session(XrSession session) {
    CHECK_SESSION(session);
    for (int i = 0; i < MAX_SWAPCHAINS; i++)
        if (rt.sc[i].used) logf_("destroy_session: swapchain %d still alive", i);
    if (rt.api == API_VULKAN) vk_session_stop();
    for (int i = 0; i < MAX_SPACES; i++) rt.spaces[i].used = 0;
    rt.session = rt.running = 0;
    rt.actions_attached = rt.synced_focused = 0;
    for (int i = 0; i < MAX_ACTION_SETS; i++) rt.sets[i].synced = 0;
    logf_("destroy_session");
    return XR_SUCCESS;
}

static XrResult begin_session(XrSession session, const XrSessionBeginInfo *info) {
    CHECK_SESSION(session);
    if (rt.running) return XR_ERROR_SESSION_RUNNING;
    if (rt.state != XR_SESSION_STATE_READY) return XR_ERROR_SESSION_NOT_READY;
    if (info->primaryViewConfigurationType != XR_VIEW_CONFIGURATION_TYPE_PRIMARY_STEREO)
        return XR_ERROR_VIEW_CONFIGURATION_TYPE_UNSUPPORTED;
    rt.running = 1;
    logf_("begin_session");
    return XR_SUCCESS;
}

static void stop_from(int state) {
    if (state == XR_SESSION_STATE_FOCUSED) push_state(XR_SESSION_STATE_VISIBLE);
    if (state == XR_SESSION_STATE_FOCUSED || state == XR_SESSION_STATE_VISIBLE) push_state(XR_SESSION_STATE_SYNCHRONIZED);
    push_state(XR_SESSION_STATE_STOPPING);
}

static XrResult request_exit_session(XrSession session) {
    CHECK_SESSION(session);
    if (!rt.running) return XR_ERROR_SESSION_NOT_RUNNING;
    logf_("request_exit_session");
    if (!rt.exit_requested && rt.state != XR_SESSION_STATE_STOPPING && rt.state != XR_SESSION_STATE_LOSS_PENDING)
        stop_from(rt.state);
    rt.exit_requested = 1;
    return XR_SUCCESS;
}

static XrResult end_session(XrSession session) {
    CHECK_SESSION(session);
    if (!rt.running) return XR_ERROR_SESSION_NOT_RUNNING;
    if (rt.state != XR_SESSION_STATE_STOPPING) return XR_ERROR_SESSION_NOT_STOPPING;
    rt.running = 0;
    logf_("end_session");
    push_state(XR_SESSION_STATE_IDLE);
    if (rt.exit_requested || rt.quit_after_stop) push_state(XR_SESSION_STATE_EXITING);
    return XR_SUCCESS;
}

static XrResult poll_event(XrInstance instance, XrEventDataBuffer *buffer) {
    CHECK_INSTANCE(instance);
    if (rt.qhead == rt.qtail) return XR_EVENT_UNAVAILABLE;
    *buffer = rt.queue[rt.qhead % QUEUE].buffer;
    rt.qhead++;
    return XR_SUCCESS;
}

/* ------------------------------------------------------------------ paths */
/* the path of a well-formed text, made when new; XR_NULL_PATH when the table is full */
static XrPath path_of(const char *text) {
    for (int i = 0; i < rt.npaths; i++)
        if (strcmp(rt.paths[i], text) == 0) return (XrPath)(i + 1);
    if (rt.npaths >= MAX_PATHS) return XR_NULL_PATH;
    snprintf(rt.paths[rt.npaths], XR_MAX_PATH_LENGTH, "%s", text);
    return (XrPath)(++rt.npaths);
}

static XrResult string_to_path(XrInstance instance, const char *text, XrPath *path) {
    CHECK_INSTANCE(instance);
    if (!text || !path) return XR_ERROR_VALIDATION_FAILURE;
    size_t n = strlen(text);
    if (n == 0 || text[0] != '/' || text[n - 1] == '/' || n >= XR_MAX_PATH_LENGTH) return XR_ERROR_PATH_FORMAT_INVALID;
    *path = path_of(text);
    return *path == XR_NULL_PATH ? XR_ERROR_PATH_COUNT_EXCEEDED : XR_SUCCESS;
}

static const char *path_text(XrPath path) {
    return path >= 1 && path <= (XrPath)rt.npaths ? rt.paths[path - 1] : NULL;
}

/* a subaction path (or none) under which the gaze is seen: none or /user/eyes_ext */
static int gaze_subaction(XrPath path) {
    return path == XR_NULL_PATH || (path_text(path) && strcmp(path_text(path), EYE_GAZE_USER) == 0);
}

/* The action (an index into rt.actions) follows the eye tracker: the extension is enabled (so XRTEST_GAZE_DEG
 * parsed), the latest eye-gaze suggestion bound it to the gaze pose, its set is attached and was active in
 * the latest xrSyncActions, and that sync found the session FOCUSED. */
static int gaze_live(int action) {
    if (action < 0 || action >= MAX_ACTIONS || !rt.enabled[EXT_EYE_GAZE] || rt.ngaze <= 0) return 0;
    const Action *a = &rt.actions[action];
    const ActionSet *s = &rt.sets[a->set];
    return a->used && a->gaze && s->used && s->attached && s->synced && rt.synced_focused;
}

static XrResult path_to_string(XrInstance instance, XrPath path, uint32_t cap, uint32_t *count, char *buffer) {
    CHECK_INSTANCE(instance);
    const char *text = path_text(path);
    if (!text) return XR_ERROR_PATH_INVALID;
    return copy_string(text, cap, count, buffer);
}

/* ------------------------------------------------------------------ spaces */
static XrResult enumerate_reference_spaces(XrSession session, uint32_t cap, uint32_t *count,
                                           XrReferenceSpaceType *types) {
    CHECK_SESSION(session);
    ENUMERATE(cap, count, 3, types[i] = (XrReferenceSpaceType)(i + 1)); /* VIEW, LOCAL, STAGE */
}

static XrResult get_reference_space_bounds_rect(XrSession session, XrReferenceSpaceType type, XrExtent2Df *bounds) {
    CHECK_SESSION(session);
    if (type < XR_REFERENCE_SPACE_TYPE_VIEW || type > XR_REFERENCE_SPACE_TYPE_STAGE)
        return XR_ERROR_REFERENCE_SPACE_UNSUPPORTED;
    bounds->width = bounds->height = 0;
    return XR_SPACE_BOUNDS_UNAVAILABLE;
}

static XrResult new_space(int type, int action, XrPath subaction, XrPosef pose, XrSpace *space) {
    for (int i = 0; i < MAX_SPACES; i++)
        if (!rt.spaces[i].used) {
            rt.spaces[i] = (Space){1, type, action, subaction, pose};
            *space = H(XrSpace, SPACE_BASE + i);
            return XR_SUCCESS;
        }
    return XR_ERROR_LIMIT_REACHED;
}

static XrResult create_reference_space(XrSession session, const XrReferenceSpaceCreateInfo *info, XrSpace *space) {
    CHECK_SESSION(session);
    if (info->referenceSpaceType < XR_REFERENCE_SPACE_TYPE_VIEW || info->referenceSpaceType > XR_REFERENCE_SPACE_TYPE_STAGE)
        return XR_ERROR_REFERENCE_SPACE_UNSUPPORTED;
    XrResult r = new_space(info->referenceSpaceType, -1, XR_NULL_PATH, info->poseInReferenceSpace, space);
    if (r == XR_SUCCESS) logf_("space create %d %d", (int)(ID(*space) - SPACE_BASE), info->referenceSpaceType);
    return r;
}

static Space *space_of(XrSpace space) {
    uintptr_t i = ID(space) - SPACE_BASE;
    return (ID(space) >= SPACE_BASE && i < MAX_SPACES && rt.spaces[i].used) ? &rt.spaces[i] : NULL;
}

static XrResult destroy_space(XrSpace space) {
    Space *s = space_of(space);
    if (!s) return XR_ERROR_HANDLE_INVALID;
    s->used = 0;
    logf_("space destroy %d", (int)(ID(space) - SPACE_BASE));
    return XR_SUCCESS;
}

/* A space's pose in LOCAL space, now; 0 when it has none: an action space that does not follow the eye tracker
 * (no controller is connected). A gaze space: the head turned by the gaze, at the head's centre, then the
 * space's poseInActionSpace. */
static int world_pose(const Space *s, XrPosef *pose) {
    if (s->action < 0) {
        *pose = compose(reference_pose((XrReferenceSpaceType)s->type), s->pose);
        return 1;
    }
    if (!gaze_live(s->action) || !gaze_subaction(s->subaction)) return 0;
    *pose = compose(compose(head_pose(), (XrPosef){gaze_rotation(), {0, 0, 0}}), s->pose);
    return 1;
}

static XrResult locate_space(XrSpace space, XrSpace base, XrTime time, XrSpaceLocation *location) {
    Space *s = space_of(space), *b = space_of(base);
    if (!s || !b) return XR_ERROR_HANDLE_INVALID;
    if (time <= 0) return XR_ERROR_TIME_INVALID;
    XrPosef world_s, world_b;
    int located = world_pose(s, &world_s) && world_pose(b, &world_b);
    location->pose = located ? compose(invert(world_b), world_s) : IDENTITY;
    location->locationFlags = 0;
    if (located)
        location->locationFlags = XR_SPACE_LOCATION_ORIENTATION_VALID_BIT | XR_SPACE_LOCATION_POSITION_VALID_BIT |
                                  XR_SPACE_LOCATION_ORIENTATION_TRACKED_BIT | XR_SPACE_LOCATION_POSITION_TRACKED_BIT;
    int gaze = located && (s->action >= 0 || b->action >= 0);      /* a sample of the eye tracker */
    for (XrBaseOutStructure *n = (XrBaseOutStructure *)location->next; n; n = n->next)
        if (n->type == XR_TYPE_EYE_GAZE_SAMPLE_TIME_EXT) ((XrEyeGazeSampleTimeEXT *)n)->time = gaze ? time : 0;
    return XR_SUCCESS;
}

/* ------------------------------------------------------------------ the action system */
static ActionSet *set_of(XrActionSet h) {
    uintptr_t i = ID(h) - ACTION_SET_BASE;
    return (ID(h) >= ACTION_SET_BASE && i < MAX_ACTION_SETS && rt.sets[i].used) ? &rt.sets[i] : NULL;
}

static Action *action_of(XrAction h) {
    uintptr_t i = ID(h) - ACTION_BASE;
    return (ID(h) >= ACTION_BASE && i < MAX_ACTIONS && rt.actions[i].used) ? &rt.actions[i] : NULL;
}

static XrResult create_action_set(XrInstance instance, const XrActionSetCreateInfo *info, XrActionSet *set) {
    CHECK_INSTANCE(instance);
    if (!info->actionSetName[0] || !info->localizedActionSetName[0]) return XR_ERROR_NAME_INVALID;
    for (int i = 0; i < MAX_ACTION_SETS; i++)
        if (rt.sets[i].used && strcmp(rt.sets[i].name, info->actionSetName) == 0) return XR_ERROR_NAME_DUPLICATED;
    for (int i = 0; i < MAX_ACTION_SETS; i++)
        if (!rt.sets[i].used) {
            rt.sets[i] = (ActionSet){1, 0, "", 0};
            snprintf(rt.sets[i].name, sizeof rt.sets[i].name, "%s", info->actionSetName);
            *set = H(XrActionSet, ACTION_SET_BASE + i);
            logf_("actions create_set %s", info->actionSetName);
            return XR_SUCCESS;
        }
    return XR_ERROR_LIMIT_REACHED;
}

static XrResult destroy_action_set(XrActionSet set) {
    ActionSet *s = set_of(set);
    if (!s) return XR_ERROR_HANDLE_INVALID;
    int index = (int)(ID(set) - ACTION_SET_BASE);
    for (int i = 0; i < MAX_ACTIONS; i++)
        if (rt.actions[i].used && rt.actions[i].set == index) rt.actions[i].used = 0;
    logf_("actions destroy_set %s", s->name);
    s->used = 0;
    return XR_SUCCESS;
}

static XrResult create_action(XrActionSet set, const XrActionCreateInfo *info, XrAction *action) {
    ActionSet *s = set_of(set);
    if (!s) return XR_ERROR_HANDLE_INVALID;
    if (s->attached) return XR_ERROR_ACTIONSETS_ALREADY_ATTACHED;
    if (!info->actionName[0] || !info->localizedActionName[0]) return XR_ERROR_NAME_INVALID;
    for (uint32_t k = 0; k < info->countSubactionPaths; k++)
        if (!path_text(info->subactionPaths[k])) return XR_ERROR_PATH_INVALID;
    int index = (int)(ID(set) - ACTION_SET_BASE);
    for (int i = 0; i < MAX_ACTIONS; i++)
        if (!rt.actions[i].used) {
            rt.actions[i] = (Action){1, index, info->actionType, "", 0};
            snprintf(rt.actions[i].name, sizeof rt.actions[i].name, "%s", info->actionName);
            *action = H(XrAction, ACTION_BASE + i);
            logf_("actions create_action %s type=%d", info->actionName, info->actionType);
            return XR_SUCCESS;
        }
    return XR_ERROR_LIMIT_REACHED;
}

static XrResult destroy_action(XrAction action) {
    Action *a = action_of(action);
    if (!a) return XR_ERROR_HANDLE_INVALID;
    a->used = 0;
    return XR_SUCCESS;
}

static XrResult suggest_bindings(XrInstance instance, const XrInteractionProfileSuggestedBinding *info) {
    CHECK_INSTANCE(instance);
    const char *profile = path_text(info->interactionProfile);
    if (!profile) return XR_ERROR_PATH_INVALID;
    if (strncmp(profile, "/interaction_profiles/", 22) != 0) return XR_ERROR_PATH_UNSUPPORTED;
    /* XR_EXT_eye_gaze_interaction's profile: only when enabled, only its gaze pose, only pose actions */
    int eyes = strcmp(profile, EYE_GAZE_PROFILE) == 0;
    if (eyes && !rt.enabled[EXT_EYE_GAZE]) return XR_ERROR_PATH_UNSUPPORTED;
    for (uint32_t k = 0; k < info->countSuggestedBindings; k++) {
        Action *a = action_of(info->suggestedBindings[k].action);
        if (!a) return XR_ERROR_HANDLE_INVALID;
        if (rt.sets[a->set].attached) return XR_ERROR_ACTIONSETS_ALREADY_ATTACHED;
        const char *binding = path_text(info->suggestedBindings[k].binding);
        if (!binding) return XR_ERROR_PATH_INVALID;
        if (eyes && (strcmp(binding, EYE_GAZE_POSE) != 0 || a->type != XR_ACTION_TYPE_POSE_INPUT))
            return XR_ERROR_PATH_UNSUPPORTED;
    }
    if (eyes) {                                    /* replaces the previous suggestion for this profile */
        for (int i = 0; i < MAX_ACTIONS; i++) rt.actions[i].gaze = 0;
        for (uint32_t k = 0; k < info->countSuggestedBindings; k++)
            action_of(info->suggestedBindings[k].action)->gaze = 1;
    }
    logf_("actions suggest %s %u", profile, info->countSuggestedBindings);
    return XR_SUCCESS;
}

/* an action of an attached set is bound to the gaze (the eye-gaze profile is the current one for /user/eyes_ext) */
static int gaze_bound(void) {
    if (!rt.enabled[EXT_EYE_GAZE]) return 0;
    for (int i = 0; i < MAX_ACTIONS; i++)
        if (rt.actions[i].used && rt.actions[i].gaze && rt.sets[rt.actions[i].set].attached) return 1;
    return 0;
}

static XrResult attach_action_sets(XrSession session, const XrSessionActionSetsAttachInfo *info) {
    CHECK_SESSION(session);
    if (rt.actions_attached) return XR_ERROR_ACTIONSETS_ALREADY_ATTACHED;
    for (uint32_t k = 0; k < info->countActionSets; k++)
        if (!set_of(info->actionSets[k])) return XR_ERROR_HANDLE_INVALID;
    for (uint32_t k = 0; k < info->countActionSets; k++) set_of(info->actionSets[k])->attached = 1;
    rt.actions_attached = 1;
    logf_("actions attach %u", info->countActionSets);
    if (gaze_bound()) {                            /* /user/eyes_ext now has the eye-gaze profile */
        XrEventDataInteractionProfileChanged e = {XR_TYPE_EVENT_DATA_INTERACTION_PROFILE_CHANGED, NULL,
                                                  H(XrSession, SESSION_ID)};
        push_event(&e, sizeof e);
        logf_("gaze profile current");
    }
    return XR_SUCCESS;
}

static XrResult get_current_interaction_profile(XrSession session, XrPath top, XrInteractionProfileState *state) {
    CHECK_SESSION(session);
    if (!rt.actions_attached) return XR_ERROR_ACTIONSET_NOT_ATTACHED;
    if (!path_text(top)) return XR_ERROR_PATH_INVALID;
    state->interactionProfile = XR_NULL_PATH;      /* no controller */
    if (strcmp(path_text(top), EYE_GAZE_USER) == 0 && gaze_bound())
        state->interactionProfile = path_of(EYE_GAZE_PROFILE);
    return XR_SUCCESS;
}

static XrResult sync_actions(XrSession session, const XrActionsSyncInfo *info) {
    CHECK_SESSION(session);
    for (uint32_t k = 0; k < info->countActiveActionSets; k++) {
        ActionSet *s = set_of(info->activeActionSets[k].actionSet);
        if (!s) return XR_ERROR_HANDLE_INVALID;
        if (!s->attached) return XR_ERROR_ACTIONSET_NOT_ATTACHED;
        XrPath sub = info->activeActionSets[k].subactionPath;
        if (sub != XR_NULL_PATH && !path_text(sub)) return XR_ERROR_PATH_INVALID;
    }
    /* this sync's sets replace the previous ones: the gaze follows those active for /user/eyes_ext */
    for (int i = 0; i < MAX_ACTION_SETS; i++) rt.sets[i].synced = 0;
    for (uint32_t k = 0; k < info->countActiveActionSets; k++)
        set_of(info->activeActionSets[k].actionSet)->synced |= gaze_subaction(info->activeActionSets[k].subactionPath);
    rt.synced_focused = rt.state == XR_SESSION_STATE_FOCUSED;
    return rt.synced_focused ? XR_SUCCESS : XR_SESSION_NOT_FOCUSED;
}

/* every action state: inactive (no controller is connected), but a pose that follows the eye tracker */
static XrResult action_state(XrSession session, const XrActionStateGetInfo *info, XrActionType want) {
    CHECK_SESSION(session);
    Action *a = action_of(info->action);
    if (!a) return XR_ERROR_HANDLE_INVALID;
    if (!rt.sets[a->set].attached) return XR_ERROR_ACTIONSET_NOT_ATTACHED;
    if (a->type != want) return XR_ERROR_ACTION_TYPE_MISMATCH;
    if (info->subactionPath != XR_NULL_PATH && !path_text(info->subactionPath)) return XR_ERROR_PATH_INVALID;
    return XR_SUCCESS;
}

static XrResult get_action_state_boolean(XrSession session, const XrActionStateGetInfo *info, XrActionStateBoolean *s) {
    XrResult r = action_state(session, info, XR_ACTION_TYPE_BOOLEAN_INPUT);
    if (r == XR_SUCCESS) s->currentState = s->changedSinceLastSync = s->isActive = XR_FALSE, s->lastChangeTime = 0;
    return r;
}

static XrResult get_action_state_float(XrSession session, const XrActionStateGetInfo *info, XrActionStateFloat *s) {
    XrResult r = action_state(session, info, XR_ACTION_TYPE_FLOAT_INPUT);
    if (r == XR_SUCCESS) s->currentState = 0, s->changedSinceLastSync = s->isActive = XR_FALSE, s->lastChangeTime = 0;
    return r;
}

static XrResult get_action_state_vector2f(XrSession session, const XrActionStateGetInfo *info,
                                          XrActionStateVector2f *s) {
    XrResult r = action_state(session, info, XR_ACTION_TYPE_VECTOR2F_INPUT);
    if (r == XR_SUCCESS) s->currentState = (XrVector2f){0, 0}, s->changedSinceLastSync = s->isActive = XR_FALSE,
                         s->lastChangeTime = 0;
    return r;
}

static XrResult get_action_state_pose(XrSession session, const XrActionStateGetInfo *info, XrActionStatePose *s) {
    XrResult r = action_state(session, info, XR_ACTION_TYPE_POSE_INPUT);
    if (r == XR_SUCCESS)
        s->isActive = gaze_live((int)(ID(info->action) - ACTION_BASE)) && gaze_subaction(info->subactionPath);
    return r;
}

static XrResult enumerate_bound_sources(XrSession session, const XrBoundSourcesForActionEnumerateInfo *info,
                                        uint32_t cap, uint32_t *count, XrPath *sources) {
    CHECK_SESSION(session);
    Action *a = action_of(info->action);
    if (!a) return XR_ERROR_HANDLE_INVALID;
    /* no controller: nothing is bound, but the gaze pose to what the eye-gaze profile binds */
    int n = rt.enabled[EXT_EYE_GAZE] && a->gaze && rt.sets[a->set].attached;
    ENUMERATE(cap, count, n, sources[i] = path_of(EYE_GAZE_POSE));
}

static XrResult get_input_source_localized_name(XrSession session, const XrInputSourceLocalizedNameGetInfo *info,
                                                uint32_t cap, uint32_t *count, char *buffer) {
    CHECK_SESSION(session);
    if (!path_text(info->sourcePath)) return XR_ERROR_PATH_INVALID;
    return copy_string("", cap, count, buffer);
}

static XrResult apply_haptic_feedback(XrSession session, const XrHapticActionInfo *info, const XrHapticBaseHeader *h) {
    CHECK_SESSION(session);
    (void)h;
    Action *a = action_of(info->action);
    if (!a) return XR_ERROR_HANDLE_INVALID;
    return a->type == XR_ACTION_TYPE_VIBRATION_OUTPUT ? XR_SUCCESS : XR_ERROR_ACTION_TYPE_MISMATCH;
}

static XrResult stop_haptic_feedback(XrSession session, const XrHapticActionInfo *info) {
    return apply_haptic_feedback(session, info, NULL);
}

static XrResult create_action_space(XrSession session, const XrActionSpaceCreateInfo *info, XrSpace *space) {
    CHECK_SESSION(session);
    Action *a = action_of(info->action);
    if (!a) return XR_ERROR_HANDLE_INVALID;
    if (a->type != XR_ACTION_TYPE_POSE_INPUT) return XR_ERROR_ACTION_TYPE_MISMATCH;
    if (info->subactionPath != XR_NULL_PATH && !path_text(info->subactionPath)) return XR_ERROR_PATH_INVALID;
    XrResult r = new_space(0, (int)(ID(info->action) - ACTION_BASE), info->subactionPath, info->poseInActionSpace, space);
    if (r == XR_SUCCESS)
        logf_("actions create_space %s %s", a->name, path_text(info->subactionPath) ? path_text(info->subactionPath) : "-");
    return r;
}

/* ------------------------------------------------------------------ swapchains */
static int64_t format_value(int k) { return rt.api == API_VULKAN ? FORMATS[k].vk : FORMATS[k].gl; }

static XrResult enumerate_swapchain_formats(XrSession session, uint32_t cap, uint32_t *count, int64_t *formats) {
    CHECK_SESSION(session);
    int64_t offered[NFORMATS];
    int n = 0;
    for (int i = 0; i < rt.nformats; i++)
        if (format_value(rt.format_index[i])) offered[n++] = format_value(rt.format_index[i]);
    ENUMERATE(cap, count, n, formats[i] = offered[i]);
}

static Swapchain *swapchain_of(XrSwapchain h) {
    uintptr_t i = ID(h) - SWAPCHAIN_BASE;
    return (ID(h) >= SWAPCHAIN_BASE && i < MAX_SWAPCHAINS && rt.sc[i].used) ? &rt.sc[i] : NULL;
}

static void destroy_images(Swapchain *s) {
    if (rt.api == API_GL) {
        gl.DeleteTextures(IMAGES, s->tex);
        return;
    }
    for (int k = 0; k < IMAGES; k++) {
        if (s->image[k]) vk.DestroyImage(rt.vk_device, s->image[k], NULL);
        if (s->memory[k]) vk.FreeMemory(rt.vk_device, s->memory[k], NULL);
    }
}

static int make_gl_images(Swapchain *s) {
    GLint previous = 0;
    gl.GetIntegerv(GL_TEXTURE_BINDING_2D, &previous);
    gl.GenTextures(IMAGES, s->tex);
    for (int k = 0; k < IMAGES; k++) {
        gl.BindTexture(GL_TEXTURE_2D, s->tex[k]);
        gl.TexImage2D(GL_TEXTURE_2D, 0, (GLint)s->format, s->width, s->height, 0, GL_RGBA, GL_UNSIGNED_BYTE, NULL);
        gl.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MIN_FILTER, GL_LINEAR);
        gl.TexParameteri(GL_TEXTURE_2D, GL_TEXTURE_MAG_FILTER, GL_LINEAR);
        gl.TexParameteri(GL_TEXTURE_2D, L_GL_TEXTURE_MAX_LEVEL, 0);
    }
    gl.BindTexture(GL_TEXTURE_2D, (GLuint)previous);
    return 1;
}

/* Images on the application's device with the usage it asked for (and TRANSFER_SRC: the runtime reads
 * them back), left in COLOR_ATTACHMENT_OPTIMAL, the layout the application acquires them in. */
static int make_vulkan_images(Swapchain *s, XrSwapchainUsageFlags usage, XrSwapchainCreateFlags flags) {
    VkImageUsageFlags vk_usage = VK_IMAGE_USAGE_TRANSFER_SRC_BIT;
    if (usage & XR_SWAPCHAIN_USAGE_COLOR_ATTACHMENT_BIT) vk_usage |= VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT;
    if (usage & XR_SWAPCHAIN_USAGE_UNORDERED_ACCESS_BIT) vk_usage |= VK_IMAGE_USAGE_STORAGE_BIT;
    if (usage & XR_SWAPCHAIN_USAGE_TRANSFER_DST_BIT) vk_usage |= VK_IMAGE_USAGE_TRANSFER_DST_BIT;
    if (usage & XR_SWAPCHAIN_USAGE_SAMPLED_BIT) vk_usage |= VK_IMAGE_USAGE_SAMPLED_BIT;
    VkImageCreateFlags create = (usage & XR_SWAPCHAIN_USAGE_MUTABLE_FORMAT_BIT) ? VK_IMAGE_CREATE_MUTABLE_FORMAT_BIT : 0;
    (void)flags;
    VkCommandBuffer cmd = vk_begin();
    for (int k = 0; k < IMAGES; k++) {
        VkImageCreateInfo info = {VK_STRUCTURE_TYPE_IMAGE_CREATE_INFO, NULL, create, VK_IMAGE_TYPE_2D,
                                  (VkFormat)s->format, {(uint32_t)s->width, (uint32_t)s->height, 1}, 1, 1,
                                  VK_SAMPLE_COUNT_1_BIT, VK_IMAGE_TILING_OPTIMAL, vk_usage, VK_SHARING_MODE_EXCLUSIVE,
                                  0, NULL, VK_IMAGE_LAYOUT_UNDEFINED};
        if (vk.CreateImage(rt.vk_device, &info, NULL, &s->image[k]) != VK_SUCCESS) return 0;
        VkMemoryRequirements req;
        vk.GetImageMemoryRequirements(rt.vk_device, s->image[k], &req);
        int type = vk_memory_type(req.memoryTypeBits, VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT);
        if (type < 0) type = vk_memory_type(req.memoryTypeBits, 0);
        VkMemoryAllocateInfo alloc = {VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO, NULL, req.size, (uint32_t)type};
        if (type < 0 || vk.AllocateMemory(rt.vk_device, &alloc, NULL, &s->memory[k]) != VK_SUCCESS ||
            vk.BindImageMemory(rt.vk_device, s->image[k], s->memory[k], 0) != VK_SUCCESS)
            return 0;
        vk_barrier(cmd, s->image[k], VK_IMAGE_LAYOUT_UNDEFINED, VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL, 0,
                   VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT);
    }
    return vk_submit_and_wait();
}

static XrResult create_swapchain(XrSession session, const XrSwapchainCreateInfo *info, XrSwapchain *out) {
    CHECK_SESSION(session);
    int format_index = -1;
    for (int i = 0; i < rt.nformats; i++)
        if (format_value(rt.format_index[i]) && format_value(rt.format_index[i]) == info->format)
            format_index = rt.format_index[i];
    if (format_index < 0) return XR_ERROR_SWAPCHAIN_FORMAT_UNSUPPORTED;
    if (info->width < 1 || info->height < 1 || info->width > 4096 || info->height > 4096 || info->sampleCount != 1 ||
        info->faceCount != 1 || info->arraySize != 1 || info->mipCount != 1)
        return XR_ERROR_VALIDATION_FAILURE;
    for (int i = 0; i < MAX_SWAPCHAINS; i++) {
        Swapchain *s = &rt.sc[i];
        if (s->used) continue;
        memset(s, 0, sizeof *s);
        s->width = (int)info->width;
        s->height = (int)info->height;
        s->format = info->format;
        s->format_index = format_index;
        s->usage = (int)info->usageFlags;
        s->released_index = -1;
        int ok = rt.api == API_GL ? make_gl_images(s) : make_vulkan_images(s, info->usageFlags, info->createFlags);
        if (!ok) {
            destroy_images(s);
            return XR_ERROR_RUNTIME_FAILURE;
        }
        s->used = 1;
        *out = H(XrSwapchain, SWAPCHAIN_BASE + i);
        logf_("create_swapchain %d format=0x%llx %dx%d", i, (unsigned long long)s->format, s->width, s->height);
        return XR_SUCCESS;
    }
    return XR_ERROR_LIMIT_REACHED;
}

static XrResult destroy_swapchain(XrSwapchain h) {
    Swapchain *s = swapchain_of(h);
    if (!s) return XR_ERROR_HANDLE_INVALID;
    destroy_images(s);
    s->used = 0;
    logf_("destroy_swapchain %d", (int)(ID(h) - SWAPCHAIN_BASE));
    return XR_SUCCESS;
}

static XrResult enumerate_swapchain_images(XrSwapchain h, uint32_t cap, uint32_t *count, XrSwapchainImageBaseHeader *images) {
    Swapchain *s = swapchain_of(h);
    if (!s) return XR_ERROR_HANDLE_INVALID;
    if (rt.api == API_GL) {
        XrSwapchainImageOpenGLKHR *gl_images = (XrSwapchainImageOpenGLKHR *)images;
        ENUMERATE(cap, count, IMAGES, {
            if (gl_images[i].type != XR_TYPE_SWAPCHAIN_IMAGE_OPENGL_KHR) return XR_ERROR_VALIDATION_FAILURE;
            gl_images[i].image = s->tex[i];
        });
    }
    XrSwapchainImageVulkanKHR *vk_images = (XrSwapchainImageVulkanKHR *)images;
    ENUMERATE(cap, count, IMAGES, {
        if (vk_images[i].type != XR_TYPE_SWAPCHAIN_IMAGE_VULKAN_KHR) return XR_ERROR_VALIDATION_FAILURE;
        vk_images[i].image = s->image[i];
    });
}

static XrResult acquire_swapchain_image(XrSwapchain h, const XrSwapchainImageAcquireInfo *info, uint32_t *index) {
    (void)info;
    Swapchain *s = swapchain_of(h);
    if (!s) return XR_ERROR_HANDLE_INVALID;
    if (s->acquired) return XR_ERROR_CALL_ORDER_INVALID; /* one at a time */
    s->acquired = 1;
    s->waited = 0;
    *index = (uint32_t)s->next;
    return XR_SUCCESS;
}

static XrResult wait_swapchain_image(XrSwapchain h, const XrSwapchainImageWaitInfo *info) {
    (void)info;
    Swapchain *s = swapchain_of(h);
    if (!s) return XR_ERROR_HANDLE_INVALID;
    if (!s->acquired || s->waited) return XR_ERROR_CALL_ORDER_INVALID;
    s->waited = 1;
    return XR_SUCCESS;
}

static XrResult release_swapchain_image(XrSwapchain h, const XrSwapchainImageReleaseInfo *info) {
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
static void sleep_until(XrTime t) {
    XrTime now = now_ns();
    if (t <= now) return;
    struct timespec ts = {(time_t)((t - now) / 1000000000LL), (long)((t - now) % 1000000000LL)};
    nanosleep(&ts, NULL);
}

static XrResult wait_frame(XrSession session, const XrFrameWaitInfo *info, XrFrameState *state) {
    (void)info;
    CHECK_SESSION(session);
    if (!rt.running) return XR_ERROR_SESSION_NOT_RUNNING;
    if (rt.paced && rt.last_wait) sleep_until(rt.last_wait + rt.period);     /* a compositor's pace */
    rt.last_wait = now_ns();
    if (rt.state == XR_SESSION_STATE_READY) push_state(XR_SESSION_STATE_SYNCHRONIZED);
    rt.next_display = rt.next_display ? rt.next_display + rt.period : rt.t0 + 2 * rt.period;
    state->predictedDisplayTime = rt.next_display;
    state->predictedDisplayPeriod = rt.period;
    state->shouldRender = rt.state == XR_SESSION_STATE_VISIBLE || rt.state == XR_SESSION_STATE_FOCUSED;
    rt.frame_waited = 1;
    return rt.state == XR_SESSION_STATE_LOSS_PENDING ? XR_SESSION_LOSS_PENDING : XR_SUCCESS;
}

static XrResult begin_frame(XrSession session, const XrFrameBeginInfo *info) {
    (void)info;
    CHECK_SESSION(session);
    if (!rt.running) return XR_ERROR_SESSION_NOT_RUNNING;
    if (!rt.frame_waited) return XR_ERROR_CALL_ORDER_INVALID;
    rt.frame_waited = 0;
    int discarded = rt.frame_begun;
    rt.frame_begun = 1;
    rt.began = now_ns();
    return discarded ? XR_FRAME_DISCARDED : XR_SUCCESS;
}

/* bytes per pixel of an image as read back and in the .npy */
static int pixel_bytes(int kind) { return kind == K_HALF || kind == K_U16 ? 8 : 4; }

/* `.npy` of rows top first: u1 (H, W, 4), <u4 (H, W), <f2 (H, W, 4) or <u2 (H, W, 4) */
static void write_npy(const char *path, const uint8_t *pixels, int w, int h, int kind) {
    FILE *f = fopen(path, "wb");
    if (!f) return;
    char header[160];
    int n = kind == K_PACKED10
        ? snprintf(header, sizeof header, "{'descr': '<u4', 'fortran_order': False, 'shape': (%d, %d), }", h, w)
        : snprintf(header, sizeof header, "{'descr': '%s', 'fortran_order': False, 'shape': (%d, %d, 4), }",
                   kind == K_HALF ? "<f2" : kind == K_U16 ? "<u2" : "|u1", h, w);
    int total = ((10 + n + 1 + 63) / 64) * 64; /* magic(6) + version(2) + len(2) + header + '\n' */
    uint16_t hlen = (uint16_t)(total - 10);
    fwrite("\x93NUMPY\x01\x00", 1, 8, f);
    fputc(hlen & 0xff, f);
    fputc(hlen >> 8, f);
    fwrite(header, 1, (size_t)n, f);
    for (int i = 10 + n; i < total - 1; i++) fputc(' ', f);
    fputc('\n', f);
    fwrite(pixels, 1, (size_t)w * h * pixel_bytes(kind), f);
    fclose(f);
}

/* The released image of `s`, whole, rows top first (GL: flipped from GL's bottom-first rows; Vulkan:
 * as stored); BGRA reordered to RGBA. Returns malloc'd pixels or NULL. */
static uint8_t *read_image(Swapchain *s) {
    int kind = FORMATS[s->format_index].kind, bpp = pixel_bytes(kind);
    size_t row = (size_t)s->width * bpp, size = row * s->height;
    uint8_t *pixels = malloc(size), *raw = malloc(size);
    if (!pixels || !raw) { free(pixels); free(raw); return NULL; }
    if (rt.api == API_GL) {
        GLint previous = 0, pack = 0, alignment = 4;
        gl.GetIntegerv(GL_TEXTURE_BINDING_2D, &previous);
        gl.GetIntegerv(L_GL_PIXEL_PACK_BUFFER_BINDING, &pack);
        gl.GetIntegerv(GL_PACK_ALIGNMENT, &alignment);
        gl.BindBuffer(L_GL_PIXEL_PACK_BUFFER, 0);
        gl.PixelStorei(GL_PACK_ALIGNMENT, 1);
        gl.BindTexture(GL_TEXTURE_2D, s->tex[s->released_index]);
        GLenum type = kind == K_HALF ? L_GL_HALF_FLOAT : kind == K_PACKED10 ? L_GL_UNSIGNED_INT_2_10_10_10_REV
                    : kind == K_U16 ? GL_UNSIGNED_SHORT : GL_UNSIGNED_BYTE;
        gl.GetTexImage(GL_TEXTURE_2D, 0, GL_RGBA, type, raw);
        gl.BindTexture(GL_TEXTURE_2D, (GLuint)previous);
        gl.PixelStorei(GL_PACK_ALIGNMENT, alignment);
        gl.BindBuffer(L_GL_PIXEL_PACK_BUFFER, (GLuint)pack);
        for (int y = 0; y < s->height; y++) memcpy(pixels + y * row, raw + (size_t)(s->height - 1 - y) * row, row);
    } else {
        VkImage image = s->image[s->released_index];
        if (!vk_readback_buffer(size)) { free(pixels); free(raw); return NULL; }
        VkCommandBuffer cmd = vk_begin();
        VkAccessFlags writes = VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT | VK_ACCESS_TRANSFER_WRITE_BIT |
                               VK_ACCESS_SHADER_WRITE_BIT;
        vk_barrier(cmd, image, VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, writes,
                   VK_ACCESS_TRANSFER_READ_BIT);
        VkBufferImageCopy region = {0, 0, 0, {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1}, {0, 0, 0},
                                    {(uint32_t)s->width, (uint32_t)s->height, 1}};
        vk.CmdCopyImageToBuffer(cmd, image, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, rt.vk_buffer, 1, &region);
        vk_barrier(cmd, image, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL,
                   VK_ACCESS_TRANSFER_READ_BIT, VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT);
        if (!vk_submit_and_wait()) { free(pixels); free(raw); return NULL; }
        memcpy(pixels, rt.vk_mapped, size);
    }
    free(raw);
    if (kind == K_BGRA8)
        for (size_t i = 0; i < size; i += 4) { uint8_t b = pixels[i]; pixels[i] = pixels[i + 2]; pixels[i + 2] = b; }
    return pixels;
}

static XrResult check_view(const XrCompositionLayerProjectionView *view) {
    Swapchain *s = swapchain_of(view->subImage.swapchain);
    if (!s || s->released_index < 0 || s->acquired) return XR_ERROR_LAYER_INVALID;
    XrOffset2Di o = view->subImage.imageRect.offset;
    XrExtent2Di e = view->subImage.imageRect.extent;
    if (o.x < 0 || o.y < 0 || e.width < 1 || e.height < 1 || o.x + e.width > s->width || o.y + e.height > s->height)
        return XR_ERROR_SWAPCHAIN_RECT_INVALID;
    return XR_SUCCESS;
}

/* View v's submitted rect. imageRect's offset counts from the image's first row: the bottom row in GL,
 * the top row in Vulkan; either way the file's rows run top first. */
static XrResult dump_view(long frame, uint32_t v, const XrCompositionLayerProjectionView *view) {
    Swapchain *s = swapchain_of(view->subImage.swapchain);
    XrOffset2Di o = view->subImage.imageRect.offset;
    XrExtent2Di e = view->subImage.imageRect.extent;
    uint8_t *all = read_image(s);
    int bpp = pixel_bytes(FORMATS[s->format_index].kind);
    uint8_t *rect = malloc((size_t)e.width * e.height * bpp);
    if (!all || !rect) { free(all); free(rect); return XR_ERROR_RUNTIME_FAILURE; }
    int top = rt.api == API_GL ? s->height - (o.y + e.height) : o.y;     /* the rect's top row in the file */
    for (int y = 0; y < e.height; y++)
        memcpy(rect + (size_t)y * e.width * bpp, all + ((size_t)(top + y) * s->width + o.x) * bpp, (size_t)e.width * bpp);
    char path[1200];
    snprintf(path, sizeof path, "%s/frame_%05ld_view_%u.npy", rt.out_dir, frame, v);
    write_npy(path, rect, e.width, e.height, FORMATS[s->format_index].kind);
    free(all);
    free(rect);
    return XR_SUCCESS;
}

static void dump_swapchains(long frame) {
    for (int i = 0; i < MAX_SWAPCHAINS; i++) {
        Swapchain *s = &rt.sc[i];
        if (!s->used || s->released_index < 0 || s->acquired) continue;
        uint8_t *all = read_image(s);
        if (!all) continue;
        char path[1200];
        snprintf(path, sizeof path, "%s/frame_%05ld_swapchain_%d.npy", rt.out_dir, frame, i);
        write_npy(path, all, s->width, s->height, FORMATS[s->format_index].kind);
        free(all);
    }
}

/* frame_times.txt: one line per xrEndFrame that reaches the runtime (header first). */
static void record_times(long frame, XrTime arrived, XrTime returned) {
    if (!rt.out_dir[0]) return;
    char path[1200];
    snprintf(path, sizeof path, "%s/frame_times.txt", rt.out_dir);
    FILE *f = fopen(path, "a");
    if (!f) return;
    if (frame == 0)
        fprintf(f, "# frame arrival_ms gap_ms begin_to_end_ms end_frame_ms: arrival since the session began; the gap "
                   "since the previous xrEndFrame arrived; from xrBeginFrame's return to xrEndFrame's arrival (the "
                   "application's rendering and every API layer's time in xrEndFrame); the runtime's own time in "
                   "it\n");
    fprintf(f, "%ld %.3f %.3f %.3f %.3f\n", frame, (double)(arrived - rt.t0) / 1e6,
            frame == 0 ? 0.0 : (double)(arrived - rt.last_end) / 1e6, rt.began ? (double)(arrived - rt.began) / 1e6 : -1.0,
            (double)(returned - arrived) / 1e6);
    fclose(f);
}

static XrResult end_frame_body(XrSession session, const XrFrameEndInfo *info, long *frame_out);

static XrResult end_frame(XrSession session, const XrFrameEndInfo *info) {
    XrTime arrived = now_ns();
    long frame = -1;
    XrResult r = end_frame_body(session, info, &frame);
    if (frame >= 0) {
        record_times(frame, arrived, now_ns());
        rt.last_end = arrived;
    }
    return r;
}

static XrResult end_frame_body(XrSession session, const XrFrameEndInfo *info, long *frame_out) {
    CHECK_SESSION(session);
    if (!rt.running) return XR_ERROR_SESSION_NOT_RUNNING;
    if (!rt.frame_begun) return XR_ERROR_CALL_ORDER_INVALID;
    if (info->environmentBlendMode != XR_ENVIRONMENT_BLEND_MODE_OPAQUE) return XR_ERROR_ENVIRONMENT_BLEND_MODE_UNSUPPORTED;
    if (info->displayTime <= 0) return XR_ERROR_TIME_INVALID;
    for (uint32_t k = 0; k < info->layerCount; k++) {
        const XrCompositionLayerBaseHeader *layer = info->layers[k];
        if (!layer || layer->type != XR_TYPE_COMPOSITION_LAYER_PROJECTION) return XR_ERROR_LAYER_INVALID;
        const XrCompositionLayerProjection *p = (const XrCompositionLayerProjection *)layer;
        if (p->viewCount != 2 || !space_of(p->space)) return XR_ERROR_VALIDATION_FAILURE;
        for (uint32_t v = 0; v < 2; v++) {
            XrResult r = check_view(&p->views[v]);
            if (r != XR_SUCCESS) return r;
        }
    }
    rt.frame_begun = 0;
    long frame = rt.end_frames++;
    *frame_out = frame;
    char views[256] = "";
    for (uint32_t k = 0; k < info->layerCount; k++) {
        const XrCompositionLayerProjection *p = (const XrCompositionLayerProjection *)info->layers[k];
        for (uint32_t v = 0; v < 2; v++) {
            const XrSwapchainSubImage *sub = &p->views[v].subImage;
            size_t used = strlen(views);
            snprintf(views + used, sizeof views - used, " %d:%d,%d,%dx%d", (int)(ID(sub->swapchain) - SWAPCHAIN_BASE),
                     sub->imageRect.offset.x, sub->imageRect.offset.y, sub->imageRect.extent.width,
                     sub->imageRect.extent.height);
            if (rt.out_dir[0]) {
                XrResult r = dump_view(frame, v, &p->views[v]);
                if (r != XR_SUCCESS) return r;
            }
        }
    }
    if (rt.out_dir[0] && rt.dump_swapchains && info->layerCount) dump_swapchains(frame);
    logf_("end_frame %ld layers=%u%s%s", frame, info->layerCount, views[0] ? " views=" : "", views[0] ? views + 1 : "");
    if (rt.state == XR_SESSION_STATE_SYNCHRONIZED && !rt.exit_requested && !rt.quit_after_stop) {
        push_state(XR_SESSION_STATE_VISIBLE);
        push_state(XR_SESSION_STATE_FOCUSED);
    }
    if (rt.loss_after && rt.end_frames == rt.loss_after) push_state(XR_SESSION_STATE_LOSS_PENDING);
    int stop = rt.stop_after && rt.end_frames >= rt.stop_after;
    stop |= rt.stop_file[0] && access(rt.stop_file, F_OK) == 0;
    if (stop && !rt.quit_after_stop && !rt.exit_requested && rt.state != XR_SESSION_STATE_STOPPING &&
        rt.state != XR_SESSION_STATE_LOSS_PENDING) {
        logf_("runtime asks the application to quit");
        rt.quit_after_stop = 1;
        stop_from(rt.state);
    }
    return rt.state == XR_SESSION_STATE_LOSS_PENDING ? XR_SESSION_LOSS_PENDING : XR_SUCCESS;
}

/* Each eye 64 mm apart about the head's centre, looking down -z, its field wider on its outer side. */
static XrResult locate_views(XrSession session, const XrViewLocateInfo *info, XrViewState *state, uint32_t cap,
                             uint32_t *count, XrView *views) {
    CHECK_SESSION(session);
    if (info->viewConfigurationType != XR_VIEW_CONFIGURATION_TYPE_PRIMARY_STEREO)
        return XR_ERROR_VIEW_CONFIGURATION_TYPE_UNSUPPORTED;
    if (info->displayTime <= 0) return XR_ERROR_TIME_INVALID;
    Space *base = space_of(info->space);
    if (!base) return XR_ERROR_HANDLE_INVALID;
    state->viewStateFlags = XR_VIEW_STATE_ORIENTATION_VALID_BIT | XR_VIEW_STATE_POSITION_VALID_BIT |
                            XR_VIEW_STATE_ORIENTATION_TRACKED_BIT | XR_VIEW_STATE_POSITION_TRACKED_BIT;
    XrPosef world_base;
    int located = world_pose(base, &world_base);
    XrPosef to_base = located ? invert(world_base) : IDENTITY;
    if (!located) state->viewStateFlags = 0;
    XrPosef head = head_pose();
    ENUMERATE(cap, count, 2, {
        float side = i == 0 ? -1.0f : 1.0f;
        XrPosef eye = compose(head, (XrPosef){{0, 0, 0, 1}, {side * 0.032f, 0, 0}});
        views[i].pose = compose(to_base, eye);
        views[i].fov = i == 0 ? (XrFovf){-0.80f, 0.70f, 0.75f, -0.78f} : (XrFovf){-0.70f, 0.80f, 0.75f, -0.78f};
    });
}

/* ------------------------------------------------------------------ dispatch */
enum { ALWAYS = -1 };                 /* or the extension (EXT_*) that provides the function */
static const struct { const char *name; PFN_xrVoidFunction fn; int extension; } FUNCTIONS[] = {
#define F(name, fn) {name, (PFN_xrVoidFunction)fn, ALWAYS}
#define E(name, fn, ext) {name, (PFN_xrVoidFunction)fn, ext}
    F("xrEnumerateInstanceExtensionProperties", enumerate_instance_extension_properties),
    F("xrCreateInstance", create_instance), F("xrDestroyInstance", destroy_instance),
    F("xrGetInstanceProperties", get_instance_properties), F("xrResultToString", result_to_string),
    F("xrStructureTypeToString", structure_type_to_string), F("xrGetSystem", get_system),
    F("xrGetSystemProperties", get_system_properties),
    F("xrEnumerateViewConfigurations", enumerate_view_configurations),
    F("xrGetViewConfigurationProperties", get_view_configuration_properties),
    F("xrEnumerateViewConfigurationViews", enumerate_view_configuration_views),
    F("xrEnumerateEnvironmentBlendModes", enumerate_environment_blend_modes),
    E("xrGetOpenGLGraphicsRequirementsKHR", get_opengl_graphics_requirements, EXT_GL),
    E("xrGetVulkanGraphicsRequirementsKHR", get_vulkan_graphics_requirements, EXT_VK1),
    E("xrGetVulkanInstanceExtensionsKHR", get_vulkan_instance_extensions, EXT_VK1),
    E("xrGetVulkanDeviceExtensionsKHR", get_vulkan_device_extensions, EXT_VK1),
    E("xrGetVulkanGraphicsDeviceKHR", get_vulkan_graphics_device, EXT_VK1),
    E("xrGetVulkanGraphicsRequirements2KHR", get_vulkan_graphics_requirements, EXT_VK2),
    E("xrGetVulkanGraphicsDevice2KHR", get_vulkan_graphics_device2, EXT_VK2),
    E("xrCreateVulkanInstanceKHR", create_vulkan_instance, EXT_VK2),
    E("xrCreateVulkanDeviceKHR", create_vulkan_device, EXT_VK2),
    F("xrCreateSession", create_session), F("xrDestroySession", destroy_session),
    F("xrEnumerateReferenceSpaces", enumerate_reference_spaces), F("xrCreateReferenceSpace", create_reference_space),
    F("xrGetReferenceSpaceBoundsRect", get_reference_space_bounds_rect),
    F("xrCreateActionSpace", create_action_space), F("xrLocateSpace", locate_space),
    F("xrDestroySpace", destroy_space), F("xrBeginSession", begin_session), F("xrEndSession", end_session),
    F("xrRequestExitSession", request_exit_session), F("xrPollEvent", poll_event),
    F("xrStringToPath", string_to_path), F("xrPathToString", path_to_string),
    F("xrCreateActionSet", create_action_set), F("xrDestroyActionSet", destroy_action_set),
    F("xrCreateAction", create_action), F("xrDestroyAction", destroy_action),
    F("xrSuggestInteractionProfileBindings", suggest_bindings),
    F("xrAttachSessionActionSets", attach_action_sets),
    F("xrGetCurrentInteractionProfile", get_current_interaction_profile), F("xrSyncActions", sync_actions),
    F("xrGetActionStateBoolean", get_action_state_boolean), F("xrGetActionStateFloat", get_action_state_float),
    F("xrGetActionStateVector2f", get_action_state_vector2f), F("xrGetActionStatePose", get_action_state_pose),
    F("xrEnumerateBoundSourcesForAction", enumerate_bound_sources),
    F("xrGetInputSourceLocalizedName", get_input_source_localized_name),
    F("xrApplyHapticFeedback", apply_haptic_feedback), F("xrStopHapticFeedback", stop_haptic_feedback),
    F("xrEnumerateSwapchainFormats", enumerate_swapchain_formats), F("xrCreateSwapchain", create_swapchain),
    F("xrDestroySwapchain", destroy_swapchain), F("xrEnumerateSwapchainImages", enumerate_swapchain_images),
    F("xrAcquireSwapchainImage", acquire_swapchain_image), F("xrWaitSwapchainImage", wait_swapchain_image),
    F("xrReleaseSwapchainImage", release_swapchain_image), F("xrWaitFrame", wait_frame),
    F("xrBeginFrame", begin_frame), F("xrEndFrame", end_frame), F("xrLocateViews", locate_views),
#undef F
#undef E
};

static XrResult get_instance_proc_addr(XrInstance instance, const char *name, PFN_xrVoidFunction *function) {
    if (!name || !function) return XR_ERROR_VALIDATION_FAILURE;
    if (strcmp(name, "xrGetInstanceProcAddr") == 0) {
        *function = (PFN_xrVoidFunction)get_instance_proc_addr;
        return XR_SUCCESS;
    }
    for (size_t i = 0; i < sizeof FUNCTIONS / sizeof FUNCTIONS[0]; i++)
        if (strcmp(name, FUNCTIONS[i].name) == 0) {
            /* an extension's functions exist once the application enabled it */
            if (FUNCTIONS[i].extension != ALWAYS && (instance == XR_NULL_HANDLE || !rt.enabled[FUNCTIONS[i].extension]))
                break;
            *function = FUNCTIONS[i].fn;
            return XR_SUCCESS;
        }
    *function = NULL;
    return XR_ERROR_FUNCTION_UNSUPPORTED;
}

EXPORT XrResult xrNegotiateLoaderRuntimeInterface(const NegotiateLoaderInfo *loader, NegotiateRuntimeRequest *request) {
    if (!loader || !request || loader->structType != 1 || request->structType != 3 || loader->minInterfaceVersion > 1 ||
        loader->maxInterfaceVersion < 1)
        return XR_ERROR_VALIDATION_FAILURE;
    request->runtimeInterfaceVersion = 1;
    request->runtimeApiVersion = XR_MAKE_VERSION(1, 0, 0);
    request->getInstanceProcAddr = get_instance_proc_addr;
    return XR_SUCCESS;
}
