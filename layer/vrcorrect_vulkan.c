/* vrcorrect's OpenXR API layer, Vulkan sessions (XR_KHR_vulkan_enable, XR_KHR_vulkan_enable2).
 *
 * A Vulkan application has no GL context, and the engine corrects with GL. Per application
 * swapchain the layer makes, on the application's VkDevice, two images of its own whose memory is
 * exportable (VK_KHR_external_memory_fd), `input` and `result`, of the swapchain's size, and the
 * engine imports both into its own headless GL context (GL_EXT_memory_object_fd). The formats hold
 * the swapchain's texels bit for bit: R32_UINT for the 32-bit formats (8-bit RGBA/BGRA, sRGB or not,
 * and A2B10G10R10), R16G16B16A16_SFLOAT for the half-float one; the engine's shader unpacks them.
 *
 * At xrEndFrame, for the frame's views:
 *  1. on the application's queue, in the layer's own command pool and buffers, each view's submitted
 *     imageRect is copied from the application's last released image into `input` (the application
 *     image goes COLOR_ATTACHMENT_OPTIMAL -> TRANSFER_SRC_OPTIMAL -> back; it is only read); the
 *     layer waits for that submission's fence;
 *  2. the engine corrects each view from `input` into `result` and calls glFinish;
 *  3. the output swapchain's image is acquired, `result`'s rects are copied into it on the
 *     application's queue (not waited for: the runtime orders its own work after it on the queue),
 *     and it is released; the frame goes down naming the output swapchains.
 * Ownership of `input` and `result` passes between the queue family and VK_QUEUE_FAMILY_EXTERNAL
 * (GL) with release/acquire barriers; both stay in VK_IMAGE_LAYOUT_GENERAL.
 *
 * Synchronisation: the fence wait in step 1 and glFinish in step 2. GL_EXT_semaphore_fd would let
 * the two APIs wait on each other without the CPU, but the GL here (Mesa llvmpipe) does not offer
 * it and no external semaphores are used; the cost is measured (`vrcorrect bench layer`).
 *
 * The device needs VK_KHR_external_memory_fd (and VK_KHR_external_memory; for a Vulkan 1.0 instance
 * VK_KHR_external_memory_capabilities and VK_KHR_get_physical_device_properties2): the layer adds
 * them where the device supports them, to the VkInstanceCreateInfo/VkDeviceCreateInfo of
 * xrCreateVulkanInstanceKHR/xrCreateVulkanDeviceKHR (enable2, on a copy) or to the lists
 * xrGetVulkanInstanceExtensionsKHR/xrGetVulkanDeviceExtensionsKHR return (enable). A session whose
 * device lacks them passes through with one log line. Every application swapchain the layer corrects
 * gets TRANSFER_SRC usage added (on a copy of its create info) so that its rects can be copied.
 */
#include "vrcorrect_layer.h"

#include <dlfcn.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <unistd.h>

static const char *const INSTANCE_EXTENSIONS[] = {"VK_KHR_external_memory_capabilities",
                                                  "VK_KHR_get_physical_device_properties2",
                                                  "VK_KHR_external_semaphore_capabilities"};
/* the first two are needed (else the session passes through); the last two are added where the device
 * offers both: external semaphores, which spare the CPU waits where the GL offers GL_EXT_semaphore_fd */
static const char *const DEVICE_EXTENSIONS[] = {"VK_KHR_external_memory", "VK_KHR_external_memory_fd",
                                                "VK_KHR_external_semaphore", "VK_KHR_external_semaphore_fd"};
#define N_INSTANCE_EXTENSIONS 3
#define N_DEVICE_EXTENSIONS 4
#define NEEDED_DEVICE_BITS 0x3u
#define SEMAPHORE_DEVICE_BITS 0xCu
#define MAX_EXTENSIONS 256
#define FENCE_TIMEOUT_NS 10000000000ULL   /* 10 s: a queue that long behind is treated as a failure */

static struct {
    void *lib;
    PFN_vkGetInstanceProcAddr GetInstanceProcAddr;
    PFN_vkEnumerateInstanceExtensionProperties EnumerateInstanceExtensionProperties;
    PFN_vkEnumerateDeviceExtensionProperties EnumerateDeviceExtensionProperties;
    VkInstance instance;                    /* the instance the application asked the runtime's device for */
    VkPhysicalDevice physical;
    /* the session */
    VkDevice device;
    VkQueue queue;
    uint32_t family;
    VkPhysicalDeviceMemoryProperties memory;
    VkCommandPool pool;
    VkCommandBuffer cmd_in, cmd_out;
    VkFence fence_in, fence_out;
    int pending_in, pending_out;
    PFN_vkGetDeviceProcAddr GetDeviceProcAddr;
    PFN_vkGetDeviceQueue GetDeviceQueue;
    PFN_vkCreateImage CreateImage;
    PFN_vkDestroyImage DestroyImage;
    PFN_vkGetImageMemoryRequirements GetImageMemoryRequirements;
    PFN_vkAllocateMemory AllocateMemory;
    PFN_vkFreeMemory FreeMemory;
    PFN_vkBindImageMemory BindImageMemory;
    PFN_vkGetMemoryFdKHR GetMemoryFdKHR;
    PFN_vkCreateCommandPool CreateCommandPool;
    PFN_vkDestroyCommandPool DestroyCommandPool;
    PFN_vkAllocateCommandBuffers AllocateCommandBuffers;
    PFN_vkResetCommandBuffer ResetCommandBuffer;
    PFN_vkBeginCommandBuffer BeginCommandBuffer;
    PFN_vkEndCommandBuffer EndCommandBuffer;
    PFN_vkCmdPipelineBarrier CmdPipelineBarrier;
    PFN_vkCmdCopyImage CmdCopyImage;
    PFN_vkQueueSubmit QueueSubmit;
    PFN_vkCreateFence CreateFence;
    PFN_vkDestroyFence DestroyFence;
    PFN_vkWaitForFences WaitForFences;
    PFN_vkResetFences ResetFences;
    /* external semaphores (VK_KHR_external_semaphore_fd), where the device and the engine's GL have them */
    PFN_vkCreateSemaphore CreateSemaphore;
    PFN_vkDestroySemaphore DestroySemaphore;
    PFN_vkGetSemaphoreFdKHR GetSemaphoreFdKHR;
    VkSemaphore ready, done;                /* copy-in finished -> GL may read; GL finished -> copy-out may run */
    int done_signalled;                     /* `done` was signalled by GL and not yet waited for */
} V;

/* ------------------------------------------------------------------ formats */
const char *vk_format_name(int64_t format) {
    switch (format) {
    case VK_FORMAT_R16G16B16A16_SFLOAT: return "VK_FORMAT_R16G16B16A16_SFLOAT";
    case VK_FORMAT_A2B10G10R10_UNORM_PACK32: return "VK_FORMAT_A2B10G10R10_UNORM_PACK32";
    case VK_FORMAT_R8G8B8A8_SRGB: return "VK_FORMAT_R8G8B8A8_SRGB";
    case VK_FORMAT_B8G8R8A8_SRGB: return "VK_FORMAT_B8G8R8A8_SRGB";
    case VK_FORMAT_R8G8B8A8_UNORM: return "VK_FORMAT_R8G8B8A8_UNORM";
    case VK_FORMAT_B8G8R8A8_UNORM: return "VK_FORMAT_B8G8R8A8_UNORM";
    default: return NULL;
    }
}

/* the format of the shared images: the same texel size, bit for bit (vkCmdCopyImage copies raw texels
 * between formats of one size class) */
static VkFormat shared_format(int64_t format) {
    return format == VK_FORMAT_R16G16B16A16_SFLOAT ? VK_FORMAT_R16G16B16A16_SFLOAT : VK_FORMAT_R32_UINT;
}

/* ------------------------------------------------------------------ the Vulkan loader */
static int load_loader(void) {
    if (V.GetInstanceProcAddr) return 1;
    void *lib = dlopen("libvulkan.so.1", RTLD_NOW | RTLD_LOCAL);
    if (!lib) return 0;
    *(void **)&V.GetInstanceProcAddr = dlsym(lib, "vkGetInstanceProcAddr");
    *(void **)&V.EnumerateInstanceExtensionProperties = dlsym(lib, "vkEnumerateInstanceExtensionProperties");
    *(void **)&V.EnumerateDeviceExtensionProperties = dlsym(lib, "vkEnumerateDeviceExtensionProperties");
    if (!V.GetInstanceProcAddr || !V.EnumerateInstanceExtensionProperties || !V.EnumerateDeviceExtensionProperties) {
        V.GetInstanceProcAddr = NULL;
        return 0;
    }
    V.lib = lib;
    return 1;
}

static int has_name(const VkExtensionProperties *props, uint32_t n, const char *name) {
    for (uint32_t i = 0; i < n; i++)
        if (strcmp(props[i].extensionName, name) == 0) return 1;
    return 0;
}

/* Which of `want` the loader (physical == NULL) or the physical device offers: a bit per name. */
static unsigned offered(VkPhysicalDevice physical, const char *const *want, int nwant) {
    if (!load_loader()) return 0;
    uint32_t n = 0;
    VkResult r = physical ? V.EnumerateDeviceExtensionProperties(physical, NULL, &n, NULL)
                          : V.EnumerateInstanceExtensionProperties(NULL, &n, NULL);
    if (r != VK_SUCCESS || n == 0) return 0;
    VkExtensionProperties *props = calloc(n, sizeof *props);
    if (!props) return 0;
    r = physical ? V.EnumerateDeviceExtensionProperties(physical, NULL, &n, props)
                 : V.EnumerateInstanceExtensionProperties(NULL, &n, props);
    unsigned bits = 0;
    for (int i = 0; i < nwant && (r == VK_SUCCESS || r == VK_INCOMPLETE); i++)
        if (has_name(props, n, want[i])) bits |= 1u << i;
    free(props);
    return bits;
}

/* `have` plus those of `want` it lacks, into `out` (at most MAX_EXTENSIONS); returns the count */
static uint32_t merged(const char *const *have, uint32_t nhave, const char *const *want, int nwant, const char **out) {
    uint32_t n = 0;
    for (uint32_t i = 0; i < nhave && n < MAX_EXTENSIONS; i++) out[n++] = have[i];
    for (int k = 0; k < nwant && n < MAX_EXTENSIONS; k++) {
        int present = 0;
        for (uint32_t i = 0; i < nhave; i++) present |= strcmp(have[i], want[k]) == 0;
        if (!present) out[n++] = want[k];
    }
    return n;
}

/* ------------------------------------------------------------------ the application's Vulkan set-up */
/* The device extensions the layer adds: the needed ones where the device offers both, then the
 * semaphore ones where it offers both of those too; 0 when it lacks a needed one. */
static unsigned device_bits(VkPhysicalDevice physical) {
    unsigned bits = offered(physical, DEVICE_EXTENSIONS, N_DEVICE_EXTENSIONS);
    if ((bits & NEEDED_DEVICE_BITS) != NEEDED_DEVICE_BITS) return 0;
    if ((bits & SEMAPHORE_DEVICE_BITS) != SEMAPHORE_DEVICE_BITS) bits &= NEEDED_DEVICE_BITS;
    return bits;
}

static XrResult XRAPI_CALL layer_GetVulkanGraphicsDeviceKHR(XrInstance instance, XrSystemId system, VkInstance vulkan,
                                                            VkPhysicalDevice *physical) {
    XrResult r = L.GetVulkanGraphicsDeviceKHR(instance, system, vulkan, physical);
    if (XR_SUCCEEDED(r) && physical) V.instance = vulkan, V.physical = *physical;
    return r;
}

static XrResult XRAPI_CALL layer_GetVulkanGraphicsDevice2KHR(XrInstance instance,
                                                             const XrVulkanGraphicsDeviceGetInfoKHR *info,
                                                             VkPhysicalDevice *physical) {
    XrResult r = L.GetVulkanGraphicsDevice2KHR(instance, info, physical);
    if (XR_SUCCEEDED(r) && info && physical) V.instance = info->vulkanInstance, V.physical = *physical;
    return r;
}

/* The runtime's space-separated list with the layer's names appended (the count-then-fill idiom). */
static XrResult extended_list(XrResult (*down)(XrInstance, XrSystemId, uint32_t, uint32_t *, char *), XrInstance instance,
                              XrSystemId system, const char *const *extra, unsigned bits, int nextra, uint32_t cap,
                              uint32_t *count, char *buffer) {
    uint32_t n = 0;
    XrResult r = down(instance, system, 0, &n, NULL);
    if (XR_FAILED(r)) return r;
    char *theirs = calloc((size_t)n + 1, 1);
    if (!theirs) return XR_ERROR_OUT_OF_MEMORY;
    if (n > 0) r = down(instance, system, n, &n, theirs);
    if (XR_FAILED(r)) { free(theirs); return r; }
    size_t size = strlen(theirs) + 1;
    for (int k = 0; k < nextra; k++) size += strlen(extra[k]) + 1;
    char *all = calloc(size, 1);
    if (!all) { free(theirs); return XR_ERROR_OUT_OF_MEMORY; }
    strcpy(all, theirs);
    for (int k = 0; k < nextra; k++) {
        if (!(bits >> k & 1)) continue;
        int present = 0;
        for (char *p = strstr(theirs, extra[k]); p && !present; p = strstr(p + 1, extra[k])) {
            char after = p[strlen(extra[k])];
            present = (p == theirs || p[-1] == ' ') && (after == 0 || after == ' ');
        }
        if (present) continue;
        if (all[0]) strcat(all, " ");
        strcat(all, extra[k]);
    }
    free(theirs);
    uint32_t need = (uint32_t)strlen(all) + 1;
    if (!count) { free(all); return XR_ERROR_VALIDATION_FAILURE; }
    *count = need;
    if (cap == 0) { free(all); return XR_SUCCESS; }
    if (cap < need || !buffer) { free(all); return XR_ERROR_SIZE_INSUFFICIENT; }
    memcpy(buffer, all, need);
    free(all);
    return XR_SUCCESS;
}

static XrResult XRAPI_CALL layer_GetVulkanInstanceExtensionsKHR(XrInstance instance, XrSystemId system, uint32_t cap,
                                                                uint32_t *count, char *buffer) {
    unsigned bits = offered(NULL, INSTANCE_EXTENSIONS, N_INSTANCE_EXTENSIONS);
    return extended_list(L.GetVulkanInstanceExtensionsKHR, instance, system, INSTANCE_EXTENSIONS, bits,
                         N_INSTANCE_EXTENSIONS, cap, count, buffer);
}

/* The device extensions are added only when the device the runtime named offers them all (known from
 * xrGetVulkanGraphicsDeviceKHR, which the application calls first); else the session passes through. */
static XrResult XRAPI_CALL layer_GetVulkanDeviceExtensionsKHR(XrInstance instance, XrSystemId system, uint32_t cap,
                                                              uint32_t *count, char *buffer) {
    unsigned bits = V.physical ? device_bits(V.physical) : 0;
    return extended_list(L.GetVulkanDeviceExtensionsKHR, instance, system, DEVICE_EXTENSIONS, bits,
                         N_DEVICE_EXTENSIONS, cap, count, buffer);
}

static XrResult XRAPI_CALL layer_CreateVulkanInstanceKHR(XrInstance instance, const XrVulkanInstanceCreateInfoKHR *info,
                                                         VkInstance *vulkan, VkResult *result) {
    if (!info || !info->vulkanCreateInfo) return L.CreateVulkanInstanceKHR(instance, info, vulkan, result);
    unsigned bits = offered(NULL, INSTANCE_EXTENSIONS, N_INSTANCE_EXTENSIONS);
    const char *wanted[N_INSTANCE_EXTENSIONS];
    int nwanted = 0;
    for (int k = 0; k < N_INSTANCE_EXTENSIONS; k++)
        if (bits >> k & 1) wanted[nwanted++] = INSTANCE_EXTENSIONS[k];
    const char *names[MAX_EXTENSIONS];
    VkInstanceCreateInfo create = *info->vulkanCreateInfo;
    create.enabledExtensionCount = merged(create.ppEnabledExtensionNames, create.enabledExtensionCount, wanted, nwanted,
                                          names);
    create.ppEnabledExtensionNames = names;
    XrVulkanInstanceCreateInfoKHR copy = *info;
    copy.vulkanCreateInfo = &create;
    return L.CreateVulkanInstanceKHR(instance, &copy, vulkan, result);
}

static XrResult XRAPI_CALL layer_CreateVulkanDeviceKHR(XrInstance instance, const XrVulkanDeviceCreateInfoKHR *info,
                                                       VkDevice *device, VkResult *result) {
    unsigned bits = info && info->vulkanPhysicalDevice ? device_bits(info->vulkanPhysicalDevice) : 0;
    if (!info || !info->vulkanCreateInfo || !bits) return L.CreateVulkanDeviceKHR(instance, info, device, result);
    const char *wanted[N_DEVICE_EXTENSIONS];
    int nwanted = 0;
    for (int k = 0; k < N_DEVICE_EXTENSIONS; k++)
        if (bits >> k & 1) wanted[nwanted++] = DEVICE_EXTENSIONS[k];
    const char *names[MAX_EXTENSIONS];
    VkDeviceCreateInfo create = *info->vulkanCreateInfo;
    create.enabledExtensionCount = merged(create.ppEnabledExtensionNames, create.enabledExtensionCount,
                                          wanted, nwanted, names);
    create.ppEnabledExtensionNames = names;
    XrVulkanDeviceCreateInfoKHR copy = *info;
    copy.vulkanCreateInfo = &create;
    return L.CreateVulkanDeviceKHR(instance, &copy, device, result);
}

PFN_xrVoidFunction vk_hook(const char *name) {
#define VHOOK(n) if (strcmp(name, "xr" #n) == 0) return L.n ? (PFN_xrVoidFunction)layer_##n : NULL;
    VHOOK(GetVulkanInstanceExtensionsKHR) VHOOK(GetVulkanDeviceExtensionsKHR) VHOOK(GetVulkanGraphicsDeviceKHR)
    VHOOK(GetVulkanGraphicsDevice2KHR) VHOOK(CreateVulkanInstanceKHR) VHOOK(CreateVulkanDeviceKHR)
#undef VHOOK
    return NULL;
}

void vk_fetch_next(XrInstance instance) {
#define NEXT(n) if (XR_FAILED(L.next_gipa(instance, "xr" #n, (PFN_xrVoidFunction *)&L.n))) L.n = NULL;
    NEXT(GetVulkanInstanceExtensionsKHR) NEXT(GetVulkanDeviceExtensionsKHR) NEXT(GetVulkanGraphicsDeviceKHR)
    NEXT(GetVulkanGraphicsDevice2KHR) NEXT(CreateVulkanInstanceKHR) NEXT(CreateVulkanDeviceKHR)
#undef NEXT
}

void vk_forget_instance(void) {
    V.instance = VK_NULL_HANDLE;
    V.physical = VK_NULL_HANDLE;
}

/* ------------------------------------------------------------------ the session */
int vk_session_start(const XrGraphicsBindingVulkanKHR *b, char *reason, size_t size) {
    if (!b->instance || !b->physicalDevice || !b->device) {
        snprintf(reason, size, "the Vulkan session's binding names no instance, physical device or device");
        return 0;
    }
    if (!load_loader()) {
        snprintf(reason, size, "libvulkan.so.1 (the Vulkan loader) could not be loaded");
        return 0;
    }
    PFN_vkGetPhysicalDeviceMemoryProperties memory_properties =
        (PFN_vkGetPhysicalDeviceMemoryProperties)V.GetInstanceProcAddr(b->instance, "vkGetPhysicalDeviceMemoryProperties");
    *(void **)&V.GetDeviceProcAddr = (void *)V.GetInstanceProcAddr(b->instance, "vkGetDeviceProcAddr");
    if (!memory_properties || !V.GetDeviceProcAddr) {
        snprintf(reason, size, "the Vulkan loader gave no vkGetDeviceProcAddr for the application's instance");
        return 0;
    }
    VkDevice d = b->device;
#define DGET(field, name) *(void **)&V.field = (void *)V.GetDeviceProcAddr(d, name); \
    if (!V.field) { snprintf(reason, size, "the application's Vulkan device has no %s", name); return 0; }
    DGET(GetDeviceQueue, "vkGetDeviceQueue") DGET(CreateImage, "vkCreateImage") DGET(DestroyImage, "vkDestroyImage")
    DGET(GetImageMemoryRequirements, "vkGetImageMemoryRequirements") DGET(AllocateMemory, "vkAllocateMemory")
    DGET(FreeMemory, "vkFreeMemory") DGET(BindImageMemory, "vkBindImageMemory")
    DGET(CreateCommandPool, "vkCreateCommandPool") DGET(DestroyCommandPool, "vkDestroyCommandPool")
    DGET(AllocateCommandBuffers, "vkAllocateCommandBuffers") DGET(ResetCommandBuffer, "vkResetCommandBuffer")
    DGET(BeginCommandBuffer, "vkBeginCommandBuffer") DGET(EndCommandBuffer, "vkEndCommandBuffer")
    DGET(CmdPipelineBarrier, "vkCmdPipelineBarrier") DGET(CmdCopyImage, "vkCmdCopyImage")
    DGET(QueueSubmit, "vkQueueSubmit") DGET(CreateFence, "vkCreateFence") DGET(DestroyFence, "vkDestroyFence")
    DGET(WaitForFences, "vkWaitForFences") DGET(ResetFences, "vkResetFences")
#undef DGET
    *(void **)&V.GetMemoryFdKHR = (void *)V.GetDeviceProcAddr(d, "vkGetMemoryFdKHR");
    if (!V.GetMemoryFdKHR) {
        snprintf(reason, size, "the application's Vulkan device was made without VK_KHR_external_memory_fd, which the "
                 "layer needs to share images with its GL engine (it adds the extension where the device offers it, "
                 "through xrCreateVulkanDeviceKHR or xrGetVulkanDeviceExtensionsKHR)");
        return 0;
    }
    /* present only when the device was made with VK_KHR_external_semaphore_fd (vkGetDeviceProcAddr gives NULL
     * for the commands of an extension the device did not enable) */
    *(void **)&V.GetSemaphoreFdKHR = (void *)V.GetDeviceProcAddr(d, "vkGetSemaphoreFdKHR");
    *(void **)&V.CreateSemaphore = (void *)V.GetDeviceProcAddr(d, "vkCreateSemaphore");
    *(void **)&V.DestroySemaphore = (void *)V.GetDeviceProcAddr(d, "vkDestroySemaphore");
    memory_properties(b->physicalDevice, &V.memory);
    V.device = d;
    V.family = b->queueFamilyIndex;
    V.GetDeviceQueue(d, b->queueFamilyIndex, b->queueIndex, &V.queue);
    VkCommandPoolCreateInfo pool = {VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO, NULL,
                                    VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT, b->queueFamilyIndex};
    VkFenceCreateInfo fence = {VK_STRUCTURE_TYPE_FENCE_CREATE_INFO, NULL, 0};
    if (!V.queue || V.CreateCommandPool(d, &pool, NULL, &V.pool) != VK_SUCCESS ||
        V.CreateFence(d, &fence, NULL, &V.fence_in) != VK_SUCCESS ||
        V.CreateFence(d, &fence, NULL, &V.fence_out) != VK_SUCCESS) {
        snprintf(reason, size, "could not make the layer's command pool and fences on the application's device");
        return 0;
    }
    VkCommandBuffer cmds[2];
    VkCommandBufferAllocateInfo alloc = {VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO, NULL, V.pool,
                                         VK_COMMAND_BUFFER_LEVEL_PRIMARY, 2};
    if (V.AllocateCommandBuffers(d, &alloc, cmds) != VK_SUCCESS) {
        snprintf(reason, size, "could not allocate the layer's command buffers");
        return 0;
    }
    V.cmd_in = cmds[0];
    V.cmd_out = cmds[1];
    return 1;
}

static int wait_fence(VkFence fence, int *pending) {
    if (!*pending) return 1;
    if (V.WaitForFences(V.device, 1, &fence, VK_TRUE, FENCE_TIMEOUT_NS) != VK_SUCCESS) return 0;
    *pending = 0;
    return 1;
}

void vk_session_stop(void) {
    if (V.device) {
        wait_fence(V.fence_in, &V.pending_in);
        wait_fence(V.fence_out, &V.pending_out);
        if (V.fence_in) V.DestroyFence(V.device, V.fence_in, NULL);
        if (V.fence_out) V.DestroyFence(V.device, V.fence_out, NULL);
        if (V.ready) V.DestroySemaphore(V.device, V.ready, NULL);
        if (V.done) V.DestroySemaphore(V.device, V.done, NULL);
        if (V.pool) V.DestroyCommandPool(V.device, V.pool, NULL);   /* frees its command buffers */
    }
    V.device = VK_NULL_HANDLE;
    V.queue = VK_NULL_HANDLE;
    V.pool = VK_NULL_HANDLE;
    V.cmd_in = V.cmd_out = VK_NULL_HANDLE;
    V.fence_in = V.fence_out = VK_NULL_HANDLE;
    V.pending_in = V.pending_out = 0;
    V.ready = V.done = VK_NULL_HANDLE;
    V.done_signalled = 0;
}

static int export_semaphore(VkSemaphore *semaphore) {
    VkExportSemaphoreCreateInfo export = {VK_STRUCTURE_TYPE_EXPORT_SEMAPHORE_CREATE_INFO, NULL,
                                          VK_EXTERNAL_SEMAPHORE_HANDLE_TYPE_OPAQUE_FD_BIT};
    VkSemaphoreCreateInfo info = {VK_STRUCTURE_TYPE_SEMAPHORE_CREATE_INFO, &export, 0};
    if (V.CreateSemaphore(V.device, &info, NULL, semaphore) != VK_SUCCESS) return -1;
    VkSemaphoreGetFdInfoKHR get = {VK_STRUCTURE_TYPE_SEMAPHORE_GET_FD_INFO_KHR, NULL, *semaphore,
                                   VK_EXTERNAL_SEMAPHORE_HANDLE_TYPE_OPAQUE_FD_BIT};
    int fd = -1;
    return V.GetSemaphoreFdKHR(V.device, &get, &fd) == VK_SUCCESS ? fd : -1;
}

/* External semaphores where the device has VK_KHR_external_semaphore_fd: two, exported to the engine,
 * which uses them where its GL has GL_EXT_semaphore_fd (begin_frame then answers 3); else the fence and
 * glFinish. The engine logs which. */
void vk_session_semaphores(void) {
    int ready_fd = -1, done_fd = -1;
    if (V.device && V.GetSemaphoreFdKHR && V.CreateSemaphore && V.DestroySemaphore) {
        ready_fd = export_semaphore(&V.ready);
        done_fd = ready_fd >= 0 ? export_semaphore(&V.done) : -1;
        if (done_fd < 0) {
            if (ready_fd >= 0) close(ready_fd);
            ready_fd = -1;
            if (V.ready) V.DestroySemaphore(V.device, V.ready, NULL);
            if (V.done) V.DestroySemaphore(V.device, V.done, NULL);
            V.ready = V.done = VK_NULL_HANDLE;
        }
    }
    PyGILState_STATE g = PyGILState_Ensure();
    PyObject *res = engine_call("import_semaphores", "(ii)", ready_fd, done_fd);   /* -1: the device has none */
    Py_XDECREF(res);
    PyGILState_Release(g);
}

/* ------------------------------------------------------------------ commands */
static VkCommandBuffer begin(VkCommandBuffer cmd, VkFence fence, int *pending) {
    if (!wait_fence(fence, pending)) return VK_NULL_HANDLE;
    V.ResetCommandBuffer(cmd, 0);
    VkCommandBufferBeginInfo info = {VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO, NULL,
                                     VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT, NULL};
    return V.BeginCommandBuffer(cmd, &info) == VK_SUCCESS ? cmd : VK_NULL_HANDLE;
}

static int submit_with(VkCommandBuffer cmd, VkFence fence, int *pending, VkSemaphore wait, VkSemaphore signal) {
    if (V.EndCommandBuffer(cmd) != VK_SUCCESS) return 0;
    V.ResetFences(V.device, 1, &fence);
    VkPipelineStageFlags stage = VK_PIPELINE_STAGE_TRANSFER_BIT;
    VkSubmitInfo info = {VK_STRUCTURE_TYPE_SUBMIT_INFO, NULL, wait ? 1u : 0u, wait ? &wait : NULL, wait ? &stage : NULL,
                         1, &cmd, signal ? 1u : 0u, signal ? &signal : NULL};
    if (V.QueueSubmit(V.queue, 1, &info, fence) != VK_SUCCESS) return 0;
    *pending = 1;
    return 1;
}

static int submit(VkCommandBuffer cmd, VkFence fence, int *pending) {
    return submit_with(cmd, fence, pending, VK_NULL_HANDLE, VK_NULL_HANDLE);
}

/* `done` signalled by GL but no copy was submitted to wait for it: an empty batch waits, so that the next
 * frame may signal it again (a binary semaphore must be waited for before it is signalled again) */
static void consume_done(void) {
    if (!V.done_signalled) return;
    VkPipelineStageFlags stage = VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT;
    VkSubmitInfo info = {VK_STRUCTURE_TYPE_SUBMIT_INFO, NULL, 1, &V.done, &stage, 0, NULL, 0, NULL};
    V.QueueSubmit(V.queue, 1, &info, VK_NULL_HANDLE);
    V.done_signalled = 0;
}

static void barrier(VkCommandBuffer cmd, VkImage image, VkImageLayout from, VkImageLayout to, VkAccessFlags src_access,
                    VkAccessFlags dst_access, VkPipelineStageFlags src_stage, VkPipelineStageFlags dst_stage,
                    uint32_t src_family, uint32_t dst_family) {
    VkImageMemoryBarrier b = {VK_STRUCTURE_TYPE_IMAGE_MEMORY_BARRIER, NULL, src_access, dst_access, from, to,
                              src_family, dst_family, image, {VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, 1}};
    V.CmdPipelineBarrier(cmd, src_stage, dst_stage, 0, 0, NULL, 0, NULL, 1, &b);
}

/* A shared image back from GL into `layout` for the queue's copy (the ownership acquired from
 * VK_QUEUE_FAMILY_EXTERNAL, where GL had it, in GENERAL), or over to GL after the copy (released from
 * `layout` into GENERAL, the layout GL reads and writes it in). */
static void from_gl(VkCommandBuffer cmd, SharedImage *s, VkImageLayout layout, VkAccessFlags access) {
    barrier(cmd, s->image, VK_IMAGE_LAYOUT_GENERAL, layout, 0, access, VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT,
            VK_PIPELINE_STAGE_TRANSFER_BIT, s->external ? VK_QUEUE_FAMILY_EXTERNAL : VK_QUEUE_FAMILY_IGNORED,
            s->external ? V.family : VK_QUEUE_FAMILY_IGNORED);
}

static void to_gl(VkCommandBuffer cmd, SharedImage *s, VkImageLayout layout, VkAccessFlags access) {
    barrier(cmd, s->image, layout, VK_IMAGE_LAYOUT_GENERAL, access, 0, VK_PIPELINE_STAGE_TRANSFER_BIT,
            VK_PIPELINE_STAGE_BOTTOM_OF_PIPE_BIT, V.family, VK_QUEUE_FAMILY_EXTERNAL);
}

/* ------------------------------------------------------------------ a chain's shared images */
static int memory_type(uint32_t bits) {
    for (uint32_t i = 0; i < V.memory.memoryTypeCount; i++)      /* device-local first, then any */
        if ((bits >> i & 1) && (V.memory.memoryTypes[i].propertyFlags & VK_MEMORY_PROPERTY_DEVICE_LOCAL_BIT)) return (int)i;
    for (uint32_t i = 0; i < V.memory.memoryTypeCount; i++)
        if (bits >> i & 1) return (int)i;
    return -1;
}

static int make_shared(SharedImage *s, VkFormat format, uint32_t width, uint32_t height) {
    VkExternalMemoryImageCreateInfo external = {VK_STRUCTURE_TYPE_EXTERNAL_MEMORY_IMAGE_CREATE_INFO, NULL,
                                                VK_EXTERNAL_MEMORY_HANDLE_TYPE_OPAQUE_FD_BIT};
    VkImageCreateInfo info = {VK_STRUCTURE_TYPE_IMAGE_CREATE_INFO, &external, 0, VK_IMAGE_TYPE_2D, format,
                              {width, height, 1}, 1, 1, VK_SAMPLE_COUNT_1_BIT, VK_IMAGE_TILING_OPTIMAL,
                              VK_IMAGE_USAGE_TRANSFER_SRC_BIT | VK_IMAGE_USAGE_TRANSFER_DST_BIT |
                                  VK_IMAGE_USAGE_SAMPLED_BIT | VK_IMAGE_USAGE_COLOR_ATTACHMENT_BIT,
                              VK_SHARING_MODE_EXCLUSIVE, 0, NULL, VK_IMAGE_LAYOUT_UNDEFINED};
    if (V.CreateImage(V.device, &info, NULL, &s->image) != VK_SUCCESS) return 0;
    VkMemoryRequirements req;
    V.GetImageMemoryRequirements(V.device, s->image, &req);
    int type = memory_type(req.memoryTypeBits);
    VkExportMemoryAllocateInfo export = {VK_STRUCTURE_TYPE_EXPORT_MEMORY_ALLOCATE_INFO, NULL,
                                         VK_EXTERNAL_MEMORY_HANDLE_TYPE_OPAQUE_FD_BIT};
    VkMemoryAllocateInfo alloc = {VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO, &export, req.size, (uint32_t)type};
    if (type < 0 || V.AllocateMemory(V.device, &alloc, NULL, &s->memory) != VK_SUCCESS) return 0;
    s->size = req.size;
    return V.BindImageMemory(V.device, s->image, s->memory, 0) == VK_SUCCESS;
}

static void free_shared(SharedImage *s) {
    if (s->image) V.DestroyImage(V.device, s->image, NULL);
    if (s->memory) V.FreeMemory(V.device, s->memory, NULL);
    memset(s, 0, sizeof *s);
}

static int export_fd(SharedImage *s) {
    VkMemoryGetFdInfoKHR info = {VK_STRUCTURE_TYPE_MEMORY_GET_FD_INFO_KHR, NULL, s->memory,
                                 VK_EXTERNAL_MEMORY_HANDLE_TYPE_OPAQUE_FD_BIT};
    int fd = -1;
    return V.GetMemoryFdKHR(V.device, &info, &fd) == VK_SUCCESS ? fd : -1;
}

int vk_chain_start(Chain *c, int chain_id, char *reason, size_t size) {
    VkFormat format = shared_format(c->format);
    if (!make_shared(&c->input, format, c->width, c->height) || !make_shared(&c->result, format, c->width, c->height)) {
        snprintf(reason, size, "could not make exportable images (VK_KHR_external_memory_fd) on the application's device");
        return 0;
    }
    /* both in GENERAL; `result` goes to GL first (it writes there), `input` stays with the queue */
    VkCommandBuffer cmd = begin(V.cmd_in, V.fence_in, &V.pending_in);
    if (!cmd) { snprintf(reason, size, "the application's queue did not finish the layer's earlier work"); return 0; }
    barrier(cmd, c->input.image, VK_IMAGE_LAYOUT_UNDEFINED, VK_IMAGE_LAYOUT_GENERAL, 0, VK_ACCESS_TRANSFER_WRITE_BIT,
            VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_QUEUE_FAMILY_IGNORED,
            VK_QUEUE_FAMILY_IGNORED);
    barrier(cmd, c->result.image, VK_IMAGE_LAYOUT_UNDEFINED, VK_IMAGE_LAYOUT_GENERAL, 0, 0,
            VK_PIPELINE_STAGE_TOP_OF_PIPE_BIT, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_QUEUE_FAMILY_IGNORED,
            VK_QUEUE_FAMILY_IGNORED);
    to_gl(cmd, &c->result, VK_IMAGE_LAYOUT_GENERAL, 0);
    if (!submit(cmd, V.fence_in, &V.pending_in) || !wait_fence(V.fence_in, &V.pending_in)) {
        snprintf(reason, size, "the layer's image set-up did not complete on the application's queue");
        return 0;
    }
    c->result.external = 1;
    int in_fd = export_fd(&c->input), out_fd = in_fd >= 0 ? export_fd(&c->result) : -1;
    if (in_fd < 0 || out_fd < 0) {
        if (in_fd >= 0) close(in_fd);
        snprintf(reason, size, "vkGetMemoryFdKHR could not export the layer's images");
        return 0;
    }
    /* the engine takes both descriptors (GL owns them once imported; the engine closes them otherwise) */
    PyGILState_STATE g = PyGILState_Ensure();
    PyObject *res = engine_call("import_images", "(iLIIiKiK)", chain_id, (long long)c->format, c->width, c->height, in_fd,
                                (unsigned long long)c->input.size, out_fd, (unsigned long long)c->result.size);
    int ok = res && PyObject_IsTrue(res);
    Py_XDECREF(res);
    PyGILState_Release(g);
    if (!ok) return 0;                             /* the engine logged why (one line) */
    c->imported = 1;
    return 1;
}

void vk_chain_stop(Chain *c, int chain_id) {
    if (c->imported && L.engine) {                 /* GL lets go of the memory first */
        PyGILState_STATE g = PyGILState_Ensure();
        PyObject *res = engine_call("release_images", "(i)", chain_id);
        Py_XDECREF(res);
        PyGILState_Release(g);
    }
    c->imported = 0;
    if (!V.device) return;
    wait_fence(V.fence_in, &V.pending_in);
    wait_fence(V.fence_out, &V.pending_out);
    free_shared(&c->input);
    free_shared(&c->result);
}

/* ------------------------------------------------------------------ a frame */
static int seen_before(const FrameView *views, uint32_t i) {
    for (uint32_t j = 0; j < i; j++)
        if (views[j].chain == views[i].chain) return 1;
    return 0;
}

/* the copies of one chain's views, between the same rects of two images */
static void copy_rects(VkCommandBuffer cmd, const FrameView *views, uint32_t nviews, Chain *c, VkImage from,
                       VkImageLayout from_layout, VkImage to, VkImageLayout to_layout) {
    VkImageCopy regions[MAX_LAYERS * MAX_VIEWS];
    uint32_t n = 0;
    for (uint32_t i = 0; i < nviews; i++) {
        if (views[i].chain != c) continue;
        XrRect2Di r = views[i].rect;
        regions[n++] = (VkImageCopy){{VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1}, {r.offset.x, r.offset.y, 0},
                                     {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1}, {r.offset.x, r.offset.y, 0},
                                     {(uint32_t)r.extent.width, (uint32_t)r.extent.height, 1}};
    }
    V.CmdCopyImage(cmd, from, from_layout, to, to_layout, n, regions);
}

/* 1. the submitted rects into each chain's `input`: waited for (a fence), or with `semaphores` signalling
 * `ready` for GL to wait on; 1 when done */
static int copy_in(const FrameView *views, uint32_t nviews, int semaphores) {
    const VkAccessFlags attachment = VK_ACCESS_COLOR_ATTACHMENT_READ_BIT | VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT;
    const VkPipelineStageFlags attachment_stage = VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT;
    for (uint32_t i = 0; i < nviews; i++)
        if (!views[i].chain->imported) return 0;      /* the reason was logged at xrCreateSwapchain */
    VkCommandBuffer cmd = begin(V.cmd_in, V.fence_in, &V.pending_in);
    if (!cmd) { pass_reason("the application's queue did not finish the layer's earlier work (10 s)"); return 0; }
    for (uint32_t i = 0; i < nviews; i++) {
        if (seen_before(views, i)) continue;
        Chain *c = views[i].chain;
        VkImage app = c->app_image[c->released];
        from_gl(cmd, &c->input, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, VK_ACCESS_TRANSFER_WRITE_BIT);
        barrier(cmd, app, VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL,
                VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT, VK_ACCESS_TRANSFER_READ_BIT, attachment_stage,
                VK_PIPELINE_STAGE_TRANSFER_BIT, VK_QUEUE_FAMILY_IGNORED, VK_QUEUE_FAMILY_IGNORED);
        copy_rects(cmd, views, nviews, c, app, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, c->input.image,
                   VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL);
        barrier(cmd, app, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL,
                VK_ACCESS_TRANSFER_READ_BIT, attachment, VK_PIPELINE_STAGE_TRANSFER_BIT, attachment_stage,
                VK_QUEUE_FAMILY_IGNORED, VK_QUEUE_FAMILY_IGNORED);
        to_gl(cmd, &c->input, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, VK_ACCESS_TRANSFER_WRITE_BIT);
    }
    if (!submit_with(cmd, V.fence_in, &V.pending_in, VK_NULL_HANDLE, semaphores ? V.ready : VK_NULL_HANDLE)) {
        pass_reason("vkQueueSubmit failed for the layer's copy");
        return 0;
    }
    for (uint32_t i = 0; i < nviews; i++) views[i].chain->input.external = 1;
    if (semaphores) return 1;                      /* GL waits on `ready` instead of this thread on the fence */
    if (!wait_fence(V.fence_in, &V.pending_in)) {
        pass_reason("the layer's copy did not complete on the application's queue within 10 s");
        return 0;
    }
    return 1;
}

/* The submitted rects into `input` and each view handed to the engine, which reads them off this thread
 * (the frame then passes through, and the next copy into `input` comes when the engine corrects). */
void vk_capture_views(const FrameView *views, uint32_t nviews) {
    if (!copy_in(views, nviews, 0)) return;
    for (uint32_t i = 0; i < nviews; i++) {
        const FrameView *f = &views[i];
        PyObject *res = engine_call("capture_vulkan", "(IiiiiiI)", f->index, (int)(f->chain - L.chains), f->rect.offset.x,
                                    f->rect.offset.y, f->rect.extent.width, f->rect.extent.height, f->view);
        Py_XDECREF(res);
    }
}

/* The frame's views corrected: `semaphores` (the engine's choice: begin_frame answered 3) orders the GL
 * work between the two copies by the external semaphores `ready` and `done`, else the copy in is waited
 * for on its fence and the GL work by glFinish. Returns 1 when the frame goes down corrected. */
int vk_correct_views(const FrameView *views, uint32_t nviews, Chain **acquired, int *nacq, double *sync_ms,
                     int semaphores) {
    const VkAccessFlags attachment = VK_ACCESS_COLOR_ATTACHMENT_READ_BIT | VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT;
    const VkPipelineStageFlags attachment_stage = VK_PIPELINE_STAGE_COLOR_ATTACHMENT_OUTPUT_BIT;
    semaphores = semaphores && V.ready && V.done;
    double t0 = now_ms();
    if (!copy_in(views, nviews, semaphores)) return 0;
    double copy_in_ms = now_ms() - t0;
    /* 2. the engine: each view from `input` into `result` (after waiting for `ready`), then glFinish or a
     * signal of `done` */
    int ok = 1;
    for (uint32_t i = 0; i < nviews && ok; i++) {
        const FrameView *f = &views[i];
        PyObject *res = engine_call("correct_vulkan", "(IiiiiiI)", f->index, (int)(f->chain - L.chains), f->rect.offset.x,
                                    f->rect.offset.y, f->rect.extent.width, f->rect.extent.height, f->view);
        ok = res && PyObject_IsTrue(res);
        Py_XDECREF(res);
    }
    double t1 = now_ms();
    PyObject *res = ok ? engine_call("finish", "()") : NULL;
    ok = res && PyObject_IsTrue(res);
    Py_XDECREF(res);
    double finish = now_ms() - t1;
    if (semaphores) {
        if (ok) V.done_signalled = 1;
        else {                                     /* `ready` must be waited for even so (the engine does) */
            PyObject *drained = engine_call("drain", "()");
            Py_XDECREF(drained);
        }
    }
    if (!ok) return 0;
    /* 3. `result` into the output images (after `done`, with semaphores) */
    if (!acquire_outputs(views, nviews, acquired, nacq)) { consume_done(); return 0; }
    double t2 = now_ms();
    VkCommandBuffer cmd = begin(V.cmd_out, V.fence_out, &V.pending_out);
    if (!cmd) {
        consume_done();
        pass_reason("the application's queue did not finish the layer's earlier work (10 s)");
        return 0;
    }
    for (uint32_t i = 0; i < nviews; i++) {
        if (seen_before(views, i)) continue;
        Chain *c = views[i].chain;
        VkImage out = c->out_image[c->out_index];
        from_gl(cmd, &c->result, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, VK_ACCESS_TRANSFER_READ_BIT);
        barrier(cmd, out, VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, attachment,
                VK_ACCESS_TRANSFER_WRITE_BIT, attachment_stage, VK_PIPELINE_STAGE_TRANSFER_BIT, VK_QUEUE_FAMILY_IGNORED,
                VK_QUEUE_FAMILY_IGNORED);
        copy_rects(cmd, views, nviews, c, c->result.image, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, out,
                   VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL);
        barrier(cmd, out, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL,
                VK_ACCESS_TRANSFER_WRITE_BIT, attachment, VK_PIPELINE_STAGE_TRANSFER_BIT, attachment_stage,
                VK_QUEUE_FAMILY_IGNORED, VK_QUEUE_FAMILY_IGNORED);
        to_gl(cmd, &c->result, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, VK_ACCESS_TRANSFER_READ_BIT);
    }
    int waits = semaphores && V.done_signalled;
    if (!submit_with(cmd, V.fence_out, &V.pending_out, waits ? V.done : VK_NULL_HANDLE, VK_NULL_HANDLE)) {
        consume_done();
        pass_reason("vkQueueSubmit failed for the layer's copy");
        return 0;
    }
    if (waits) V.done_signalled = 0;
    double copy_out = now_ms() - t2;
    sync_ms[0] = copy_in_ms;
    sync_ms[1] = finish;
    sync_ms[2] = copy_out;
    return 1;
}
