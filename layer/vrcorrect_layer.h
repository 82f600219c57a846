/* vrcorrect's OpenXR API layer: what vrcorrect_layer.c (negotiation, dispatch, the embedded Python,
 * OpenGL sessions) and vrcorrect_vulkan.c (Vulkan sessions) share. See vrcorrect_layer.c's header. */
#ifndef VRCORRECT_LAYER_H
#define VRCORRECT_LAYER_H

#define _GNU_SOURCE
#include <Python.h>
#include <stdint.h>
#include <time.h>

#include <X11/Xlib.h>
#include <GL/glx.h>
#include <vulkan/vulkan.h>
#define XR_USE_GRAPHICS_API_OPENGL
#define XR_USE_GRAPHICS_API_VULKAN
#define XR_USE_PLATFORM_XLIB
#include <openxr/openxr.h>
#include <openxr/openxr_platform.h>

#define MAX_SWAPCHAINS 32
#define MAX_IMAGES 8
#define MAX_VIEWS 4
#define MAX_LAYERS 16

enum { API_NONE, API_GL, API_VULKAN };

/* A Vulkan image of the layer's own whose memory GL imports (VK_KHR_external_memory_fd). */
typedef struct {
    VkImage image;
    VkDeviceMemory memory;
    VkDeviceSize size;
    int external;                    /* its ownership was released to VK_QUEUE_FAMILY_EXTERNAL (GL's turn) */
} SharedImage;

typedef struct {
    XrSwapchain app, out;            /* out == XR_NULL_HANDLE: passed through */
    XrSession session;
    int64_t format;
    uint32_t width, height, app_count, out_count;
    GLuint app_tex[MAX_IMAGES], out_tex[MAX_IMAGES];          /* OpenGL sessions */
    VkImage app_image[MAX_IMAGES], out_image[MAX_IMAGES];     /* Vulkan sessions */
    SharedImage input, result;       /* Vulkan: the submitted rects copied out, the correction to copy in */
    int imported;                    /* Vulkan: the engine imported input and result */
    uint32_t acquired[MAX_IMAGES];   /* FIFO of acquired, not yet released indices */
    int nacquired;
    int released;                    /* last released index, -1 none */
    uint32_t out_index;              /* the output image acquired for this frame */
} Chain;

/* One view of a projection layer in the frame being corrected. */
typedef struct {
    uint32_t layer, view, index;     /* layer k, view v in it, and the frame's running view number */
    Chain *chain;
    XrRect2Di rect;
} FrameView;

typedef struct {
    PFN_xrGetInstanceProcAddr next_gipa;
    XrInstance instance;
    PFN_xrDestroyInstance DestroyInstance;
    PFN_xrCreateSession CreateSession;
    PFN_xrDestroySession DestroySession;
    PFN_xrCreateSwapchain CreateSwapchain;
    PFN_xrDestroySwapchain DestroySwapchain;
    PFN_xrEnumerateSwapchainImages EnumerateSwapchainImages;
    PFN_xrAcquireSwapchainImage AcquireSwapchainImage;
    PFN_xrWaitSwapchainImage WaitSwapchainImage;
    PFN_xrReleaseSwapchainImage ReleaseSwapchainImage;
    PFN_xrEndFrame EndFrame;
    PFN_xrEnumerateViewConfigurationViews EnumerateViewConfigurationViews;
    /* XR_KHR_vulkan_enable and XR_KHR_vulkan_enable2 (NULL when the application did not enable them) */
    PFN_xrGetVulkanInstanceExtensionsKHR GetVulkanInstanceExtensionsKHR;
    PFN_xrGetVulkanDeviceExtensionsKHR GetVulkanDeviceExtensionsKHR;
    PFN_xrGetVulkanGraphicsDeviceKHR GetVulkanGraphicsDeviceKHR;
    PFN_xrGetVulkanGraphicsDevice2KHR GetVulkanGraphicsDevice2KHR;
    PFN_xrCreateVulkanInstanceKHR CreateVulkanInstanceKHR;
    PFN_xrCreateVulkanDeviceKHR CreateVulkanDeviceKHR;
    XrSession session;               /* the corrected session, or XR_NULL_HANDLE */
    int api;                         /* API_GL or API_VULKAN while a session is corrected */
    GLXContext context;              /* OpenGL: the session's context */
    Chain chains[MAX_SWAPCHAINS];
    PyObject *engine;                /* vrcorrect.runtime.layer.engine.Engine, or NULL */
    int python_failed, engine_failed;
    int we_initialised;
    char last_reason[256];
} LayerState;

extern LayerState L;

void layer_log(const char *fmt, ...) __attribute__((format(printf, 1, 2)));
void pass_reason(const char *reason);
Chain *chain_of(XrSwapchain h);
PyObject *engine_call(const char *method, const char *format, ...);
double now_ms(void);
int format_allowed(int64_t format);
int acquire_outputs(const FrameView *views, uint32_t nviews, Chain **acquired, int *nacq);

/* vrcorrect_vulkan.c */
const char *vk_format_name(int64_t format);        /* NULL: not a format the layer corrects */
PFN_xrVoidFunction vk_hook(const char *name);      /* the layer's xrGetVulkan.../xrCreateVulkan... hooks */
void vk_fetch_next(XrInstance instance);           /* fills L's XR_KHR_vulkan_enable(2) pointers */
void vk_forget_instance(void);
int vk_session_start(const XrGraphicsBindingVulkanKHR *binding, char *reason, size_t size);
void vk_session_stop(void);
int vk_chain_start(Chain *c, int chain_id, char *reason, size_t size);
void vk_chain_stop(Chain *c, int chain_id);
int vk_correct_views(const FrameView *views, uint32_t nviews, Chain **acquired, int *nacq, double *sync_ms,
                     int semaphores);
void vk_session_semaphores(void);                  /* exports the external semaphores (if any) to the engine */
void vk_capture_views(const FrameView *views, uint32_t nviews);   /* the rects into `input`, for the engine */

/* vrcorrect_gaze.c: the eye tracker (XR_EXT_eye_gaze_interaction) for a foveated correction */
XrResult gaze_create_instance(const XrInstanceCreateInfo *info,
                              XrResult (*down)(const XrInstanceCreateInfo *, void *), void *context);
void gaze_start(XrInstance instance);              /* after the instance is made and L.next_gipa set */
PFN_xrVoidFunction gaze_hook(const char *name);    /* NULL unless the layer asked for the eye tracker */
void gaze_views(const XrFrameEndInfo *info, const FrameView *views, uint32_t nviews);   /* under the GIL */
void gaze_session_end(XrSession session);
#endif
