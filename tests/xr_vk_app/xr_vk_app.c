/* A small OpenXR Vulkan application for vrcorrect's layer tests (test equipment; it knows nothing of
 * vrcorrect), the Vulkan twin of tests/xr_gl_app: it reaches the cases hello_xr cannot (a sub-rect,
 * a double-width swapchain, every swapchain format, an application that ignores the runtime's
 * device extensions). It loads the OpenXR loader named by APP_LOADER, makes its Vulkan instance
 * and device the way XR_KHR_vulkan_enable2 (default) or XR_KHR_vulkan_enable says, runs one
 * session, and submits, for each eye, a known image (raw RGBA8 bytes, top row first, converted to
 * the swapchain's format) into its own swapchains every frame, until APP_FRAMES frames were
 * submitted; then it asks to exit and tears everything down.
 *
 * Environment:
 *   APP_LOADER        path of libopenxr_loader.so (required)
 *   APP_IMAGE_LEFT    raw image of the left eye (W*H*4 bytes RGBA8, top row first; W x H the view size)
 *   APP_IMAGE_RIGHT   the right eye's
 *   APP_FRAMES        frames to submit (default 3)
 *   APP_FORMAT        the swapchains' format, or "LEFT,RIGHT" for one each: srgb (R8G8B8A8_SRGB, default),
 *                     rgba8 (R8G8B8A8_UNORM), bgra8srgb (B8G8R8A8_SRGB), bgra8 (B8G8R8A8_UNORM), rgb10a2
 *                     (A2B10G10R10_UNORM_PACK32), rgba16f (R16G16B16A16_SFLOAT), rgba16 (R16G16B16A16_UNORM).
 *                     A byte v becomes v (8-bit), round(v * 1023 / 255) (10-bit; alpha 3), v / 255 * APP_GAIN
 *                     (half float; alpha 1), v * 257 (16-bit)
 *   APP_GAIN          the half-float images' scale (default 1; above 1 they hold values above 1, as HDR does)
 *   APP_RECT          "x,y,w,h": submit this imageRect (Vulkan pixels from the top left) instead of all
 *   APP_SIDE_BY_SIDE  "1": one swapchain twice as wide (the left eye's format), the left eye's picture and
 *                     view in its left half
 *   APP_ENABLE        "1": XR_KHR_vulkan_enable (the application lists and enables the runtime's Vulkan
 *                     extensions itself) instead of XR_KHR_vulkan_enable2
 *   APP_IGNORE_EXTENSIONS  "1" (with APP_ENABLE): make the device without the extensions the runtime lists,
 *                     as a careless application might
 *   APP_CHECK         "1": after each xrEndFrame read the application's released images back (its swapchains
 *                     get TRANSFER_SRC usage for it) and fail unless they hold exactly what it wrote
 *   APP_LAYERS        comma-separated API layer names to enable in xrCreateInstance
 *   APP_STOP_FILE     run until this file exists (then at least APP_FRAMES frames), 20 ms a frame
 * Prints one line per step to stdout; exit status 0 when the session life cycle completed.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <math.h>
#include <stdint.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include <vulkan/vulkan.h>
#define XR_USE_GRAPHICS_API_VULKAN
#include <openxr/openxr.h>
#include <openxr/openxr_platform.h>

#include "../xr_app_common.h"

static PFN_xrGetInstanceProcAddr gipa;
static XrInstance instance;

#define FAIL(...) do { fprintf(stderr, "xr_vk_app: " __VA_ARGS__); fputc('\n', stderr); return 1; } while (0)
#define CHECK(call) do { XrResult r_ = (call); if (XR_FAILED(r_)) FAIL("%s failed: %d", #call, r_); } while (0)
#define VK(call) do { VkResult v_ = (call); if (v_ != VK_SUCCESS) FAIL("%s failed: %d", #call, v_); } while (0)
#define FN(name) PFN_##name name = NULL; gipa(instance, #name, (PFN_xrVoidFunction *)&name); \
    if (!name) FAIL("no %s", #name)

typedef struct { const char *name; VkFormat format; int bpp; } Format;
static const Format FORMATS[] = {
    {"srgb", VK_FORMAT_R8G8B8A8_SRGB, 4}, {"rgba8", VK_FORMAT_R8G8B8A8_UNORM, 4},
    {"bgra8srgb", VK_FORMAT_B8G8R8A8_SRGB, 4}, {"bgra8", VK_FORMAT_B8G8R8A8_UNORM, 4},
    {"rgb10a2", VK_FORMAT_A2B10G10R10_UNORM_PACK32, 4}, {"rgba16f", VK_FORMAT_R16G16B16A16_SFLOAT, 8},
    {"rgba16", VK_FORMAT_R16G16B16A16_UNORM, 8},
};

static const Format *format_named(const char *name, size_t n) {
    for (size_t i = 0; i < sizeof FORMATS / sizeof FORMATS[0]; i++)
        if (strlen(FORMATS[i].name) == n && strncmp(FORMATS[i].name, name, n) == 0) return &FORMATS[i];
    return NULL;
}

static uint16_t half(float f) {                 /* float to IEEE half, round to nearest (normal range) */
    uint32_t x;
    memcpy(&x, &f, 4);
    uint32_t sign = (x >> 16) & 0x8000;
    int e = (int)((x >> 23) & 0xff) - 127 + 15;
    uint32_t m = x & 0x7fffff;
    if (f == 0.0f) return (uint16_t)sign;
    if (e <= 0) return (uint16_t)sign;           /* too small for a half: 0 (never the case for v / 255) */
    if (e >= 31) return (uint16_t)(sign | 0x7c00);
    uint32_t h = sign | ((uint32_t)e << 10) | (m >> 13);
    if ((m & 0x1fff) > 0x1000 || ((m & 0x1fff) == 0x1000 && (h & 1))) h++;
    return (uint16_t)h;
}

/* The picture (RGBA8, top row first) in `f`'s bytes, w x h. */
static void convert(const unsigned char *rgba, int w, int h, const Format *f, float gain, unsigned char *out) {
    for (int i = 0; i < w * h; i++) {
        const unsigned char *p = rgba + 4 * i;
        switch (f->format) {
        case VK_FORMAT_B8G8R8A8_SRGB: case VK_FORMAT_B8G8R8A8_UNORM:
            out[4 * i] = p[2], out[4 * i + 1] = p[1], out[4 * i + 2] = p[0], out[4 * i + 3] = p[3];
            break;
        case VK_FORMAT_A2B10G10R10_UNORM_PACK32: {
            uint32_t r = (uint32_t)lround(p[0] * 1023.0 / 255.0), g = (uint32_t)lround(p[1] * 1023.0 / 255.0),
                     b = (uint32_t)lround(p[2] * 1023.0 / 255.0);
            uint32_t v = r | g << 10 | b << 20 | 3u << 30;
            memcpy(out + 4 * i, &v, 4);
            break;
        }
        case VK_FORMAT_R16G16B16A16_SFLOAT: {
            uint16_t v[4] = {half(p[0] / 255.0f * gain), half(p[1] / 255.0f * gain), half(p[2] / 255.0f * gain),
                             half(1.0f)};
            memcpy(out + 8 * i, v, 8);
            break;
        }
        case VK_FORMAT_R16G16B16A16_UNORM: {
            uint16_t v[4] = {(uint16_t)(p[0] * 257), (uint16_t)(p[1] * 257), (uint16_t)(p[2] * 257), (uint16_t)(p[3] * 257)};
            memcpy(out + 8 * i, v, 8);
            break;
        }
        default:
            memcpy(out + 4 * i, p, 4);
        }
    }
}

/* ---------------------------------------------------------------- Vulkan helpers */
static VkDevice device;
static VkPhysicalDevice physical;
static VkQueue queue;
static VkCommandBuffer cmd;
static VkFence fence;

typedef struct { VkBuffer buffer; VkDeviceMemory memory; void *mapped; VkDeviceSize size; } Buffer;

static int host_buffer(VkDeviceSize size, VkBufferUsageFlags usage, Buffer *b) {
    VkBufferCreateInfo info = {VK_STRUCTURE_TYPE_BUFFER_CREATE_INFO, NULL, 0, size, usage, VK_SHARING_MODE_EXCLUSIVE, 0, NULL};
    if (vkCreateBuffer(device, &info, NULL, &b->buffer) != VK_SUCCESS) return 0;
    VkMemoryRequirements req;
    vkGetBufferMemoryRequirements(device, b->buffer, &req);
    VkPhysicalDeviceMemoryProperties props;
    vkGetPhysicalDeviceMemoryProperties(physical, &props);
    const VkMemoryPropertyFlags want = VK_MEMORY_PROPERTY_HOST_VISIBLE_BIT | VK_MEMORY_PROPERTY_HOST_COHERENT_BIT;
    uint32_t type = 0;
    while (type < props.memoryTypeCount && !((req.memoryTypeBits >> type & 1) &&
                                             (props.memoryTypes[type].propertyFlags & want) == want))
        type++;
    VkMemoryAllocateInfo alloc = {VK_STRUCTURE_TYPE_MEMORY_ALLOCATE_INFO, NULL, req.size, type};
    if (type == props.memoryTypeCount || vkAllocateMemory(device, &alloc, NULL, &b->memory) != VK_SUCCESS) return 0;
    b->size = size;
    return vkBindBufferMemory(device, b->buffer, b->memory, 0) == VK_SUCCESS &&
           vkMapMemory(device, b->memory, 0, VK_WHOLE_SIZE, 0, &b->mapped) == VK_SUCCESS;
}

static void free_buffer(Buffer *b) {
    vkUnmapMemory(device, b->memory);
    vkDestroyBuffer(device, b->buffer, NULL);
    vkFreeMemory(device, b->memory, NULL);
}

static void barrier(VkImage image, VkImageLayout from, VkImageLayout to, VkAccessFlags src, VkAccessFlags dst) {
    VkImageMemoryBarrier b = {VK_STRUCTURE_TYPE_IMAGE_MEMORY_BARRIER, NULL, src, dst, from, to, VK_QUEUE_FAMILY_IGNORED,
                              VK_QUEUE_FAMILY_IGNORED, image, {VK_IMAGE_ASPECT_COLOR_BIT, 0, 1, 0, 1}};
    vkCmdPipelineBarrier(cmd, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, VK_PIPELINE_STAGE_ALL_COMMANDS_BIT, 0, 0, NULL, 0, NULL,
                         1, &b);
}

static int run_commands(void) {
    if (vkEndCommandBuffer(cmd) != VK_SUCCESS) return 0;
    VkSubmitInfo submit = {VK_STRUCTURE_TYPE_SUBMIT_INFO, NULL, 0, NULL, NULL, 1, &cmd, 0, NULL};
    if (vkResetFences(device, 1, &fence) != VK_SUCCESS || vkQueueSubmit(queue, 1, &submit, fence) != VK_SUCCESS)
        return 0;
    return vkWaitForFences(device, 1, &fence, VK_TRUE, UINT64_MAX) == VK_SUCCESS;
}

static void begin_commands(void) {
    vkResetCommandBuffer(cmd, 0);
    VkCommandBufferBeginInfo begin = {VK_STRUCTURE_TYPE_COMMAND_BUFFER_BEGIN_INFO, NULL,
                                      VK_COMMAND_BUFFER_USAGE_ONE_TIME_SUBMIT_BIT, NULL};
    vkBeginCommandBuffer(cmd, &begin);
}

/* "a b c" (modified in place) into names */
static uint32_t split(char *list, const char **names, uint32_t cap) {
    uint32_t n = 0;
    for (char *tok = strtok(list, " "); tok && n < cap; tok = strtok(NULL, " ")) names[n++] = tok;
    return n;
}

int main(void) {
    setvbuf(stdout, NULL, _IOLBF, 0);
    const char *loader = getenv("APP_LOADER");
    if (!loader) FAIL("APP_LOADER is not set");
    void *lib = dlopen(loader, RTLD_NOW);
    if (!lib) FAIL("cannot load %s: %s", loader, dlerror());
    gipa = (PFN_xrGetInstanceProcAddr)dlsym(lib, "xrGetInstanceProcAddr");
    if (!gipa) FAIL("no xrGetInstanceProcAddr in %s", loader);
    int frames_wanted = getenv("APP_FRAMES") ? atoi(getenv("APP_FRAMES")) : 3;
    float gain = getenv("APP_GAIN") ? (float)atof(getenv("APP_GAIN")) : 1.0f;
    int legacy = getenv("APP_ENABLE") != NULL, ignore = getenv("APP_IGNORE_EXTENSIONS") != NULL;
    int check = getenv("APP_CHECK") != NULL;
    const Format *formats[2] = {&FORMATS[0], &FORMATS[0]};
    if (getenv("APP_FORMAT")) {
        const char *spec = getenv("APP_FORMAT"), *comma = strchr(spec, ',');
        formats[0] = format_named(spec, comma ? (size_t)(comma - spec) : strlen(spec));
        formats[1] = comma ? format_named(comma + 1, strlen(comma + 1)) : formats[0];
        if (!formats[0] || !formats[1]) FAIL("APP_FORMAT: unknown format in %s", spec);
    }

    /* ---------------------------------------------------------------- instance, system */
    const char *extensions[] = {legacy ? XR_KHR_VULKAN_ENABLE_EXTENSION_NAME : XR_KHR_VULKAN_ENABLE2_EXTENSION_NAME};
    char layer_buf[1024] = "";
    const char *layers[8];
    uint32_t nlayers = 0;
    if (getenv("APP_LAYERS")) {
        snprintf(layer_buf, sizeof layer_buf, "%s", getenv("APP_LAYERS"));
        for (char *tok = strtok(layer_buf, ","); tok && nlayers < 8; tok = strtok(NULL, ",")) layers[nlayers++] = tok;
    }
    XrInstanceCreateInfo ici = {XR_TYPE_INSTANCE_CREATE_INFO};
    snprintf(ici.applicationInfo.applicationName, XR_MAX_APPLICATION_NAME_SIZE, "xr_vk_app");
    ici.applicationInfo.apiVersion = XR_MAKE_VERSION(1, 0, 0);
    ici.enabledExtensionCount = 1;
    ici.enabledExtensionNames = extensions;
    ici.enabledApiLayerCount = nlayers;
    ici.enabledApiLayerNames = layers;
    PFN_xrCreateInstance xrCreateInstance_ = NULL;
    gipa(XR_NULL_HANDLE, "xrCreateInstance", (PFN_xrVoidFunction *)&xrCreateInstance_);
    if (!xrCreateInstance_) FAIL("no xrCreateInstance");
    CHECK(xrCreateInstance_(&ici, &instance));
    printf("instance %s\n", extensions[0]);
    FN(xrGetSystem); FN(xrEnumerateViewConfigurationViews); FN(xrCreateSession); FN(xrDestroySession);
    FN(xrCreateReferenceSpace); FN(xrDestroySpace); FN(xrCreateSwapchain); FN(xrDestroySwapchain);
    FN(xrEnumerateSwapchainImages); FN(xrAcquireSwapchainImage); FN(xrWaitSwapchainImage); FN(xrReleaseSwapchainImage);
    FN(xrPollEvent); FN(xrBeginSession); FN(xrEndSession); FN(xrRequestExitSession); FN(xrWaitFrame); FN(xrBeginFrame);
    FN(xrEndFrame); FN(xrLocateViews); FN(xrDestroyInstance);
    XrSystemGetInfo sgi = {XR_TYPE_SYSTEM_GET_INFO, NULL, XR_FORM_FACTOR_HEAD_MOUNTED_DISPLAY};
    XrSystemId system;
    CHECK(xrGetSystem(instance, &sgi, &system));
    XrViewConfigurationView vcv[2] = {{XR_TYPE_VIEW_CONFIGURATION_VIEW}, {XR_TYPE_VIEW_CONFIGURATION_VIEW}};
    uint32_t nv = 0;
    CHECK(xrEnumerateViewConfigurationViews(instance, system, XR_VIEW_CONFIGURATION_TYPE_PRIMARY_STEREO, 2, &nv, vcv));
    int W = (int)vcv[0].recommendedImageRectWidth, H = (int)vcv[0].recommendedImageRectHeight;
    size_t bytes = (size_t)W * H * 4;
    unsigned char *pictures[2] = {read_raw(getenv("APP_IMAGE_LEFT"), bytes), read_raw(getenv("APP_IMAGE_RIGHT"), bytes)};
    for (int e = 0; e < 2; e++)
        if (!pictures[e]) FAIL("cannot read the %s image (%zu bytes expected)", e ? "right" : "left", bytes);
    int rect[4] = {0, 0, W, H};
    if (getenv("APP_RECT") && sscanf(getenv("APP_RECT"), "%d,%d,%d,%d", &rect[0], &rect[1], &rect[2], &rect[3]) != 4)
        FAIL("APP_RECT must be x,y,w,h");

    /* ---------------------------------------------------------------- Vulkan instance and device, as the extension says */
    VkApplicationInfo app_info = {VK_STRUCTURE_TYPE_APPLICATION_INFO, NULL, "xr_vk_app", 1, "none", 1, VK_API_VERSION_1_0};
    VkInstanceCreateInfo vici = {VK_STRUCTURE_TYPE_INSTANCE_CREATE_INFO, NULL, 0, &app_info, 0, NULL, 0, NULL};
    VkInstance vk_instance;
    char names_buf[4096] = "";
    const char *names[64];
    if (legacy) {
        FN(xrGetVulkanGraphicsRequirementsKHR); FN(xrGetVulkanInstanceExtensionsKHR); FN(xrGetVulkanGraphicsDeviceKHR);
        FN(xrGetVulkanDeviceExtensionsKHR);
        XrGraphicsRequirementsVulkanKHR req = {XR_TYPE_GRAPHICS_REQUIREMENTS_VULKAN_KHR};
        CHECK(xrGetVulkanGraphicsRequirementsKHR(instance, system, &req));
        uint32_t n = 0;
        CHECK(xrGetVulkanInstanceExtensionsKHR(instance, system, 0, &n, NULL));
        if (n > sizeof names_buf) FAIL("instance extension list too long");
        CHECK(xrGetVulkanInstanceExtensionsKHR(instance, system, n, &n, names_buf));
        printf("runtime instance extensions: %s\n", names_buf);
        vici.enabledExtensionCount = split(names_buf, names, 64);
        vici.ppEnabledExtensionNames = names;
        VK(vkCreateInstance(&vici, NULL, &vk_instance));
        CHECK(xrGetVulkanGraphicsDeviceKHR(instance, system, vk_instance, &physical));
    } else {
        FN(xrGetVulkanGraphicsRequirements2KHR); FN(xrCreateVulkanInstanceKHR); FN(xrGetVulkanGraphicsDevice2KHR);
        XrGraphicsRequirementsVulkan2KHR req = {XR_TYPE_GRAPHICS_REQUIREMENTS_VULKAN2_KHR};
        CHECK(xrGetVulkanGraphicsRequirements2KHR(instance, system, &req));
        XrVulkanInstanceCreateInfoKHR xvici = {XR_TYPE_VULKAN_INSTANCE_CREATE_INFO_KHR, NULL, system, 0,
                                               vkGetInstanceProcAddr, &vici, NULL};
        VkResult vr;
        CHECK(xrCreateVulkanInstanceKHR(instance, &xvici, &vk_instance, &vr));
        VK(vr);
        XrVulkanGraphicsDeviceGetInfoKHR gi = {XR_TYPE_VULKAN_GRAPHICS_DEVICE_GET_INFO_KHR, NULL, system, vk_instance};
        CHECK(xrGetVulkanGraphicsDevice2KHR(instance, &gi, &physical));
    }
    uint32_t nfamilies = 0;
    vkGetPhysicalDeviceQueueFamilyProperties(physical, &nfamilies, NULL);
    VkQueueFamilyProperties families[16];
    if (nfamilies > 16) nfamilies = 16;
    vkGetPhysicalDeviceQueueFamilyProperties(physical, &nfamilies, families);
    uint32_t family = 0;
    while (family < nfamilies && !(families[family].queueFlags & VK_QUEUE_GRAPHICS_BIT)) family++;
    if (family == nfamilies) FAIL("no graphics queue");
    float priority = 1.0f;
    VkDeviceQueueCreateInfo qci = {VK_STRUCTURE_TYPE_DEVICE_QUEUE_CREATE_INFO, NULL, 0, family, 1, &priority};
    VkDeviceCreateInfo dci = {VK_STRUCTURE_TYPE_DEVICE_CREATE_INFO, NULL, 0, 1, &qci, 0, NULL, 0, NULL, NULL};
    if (legacy) {
        PFN_xrGetVulkanDeviceExtensionsKHR xrGetVulkanDeviceExtensionsKHR = NULL;
        gipa(instance, "xrGetVulkanDeviceExtensionsKHR", (PFN_xrVoidFunction *)&xrGetVulkanDeviceExtensionsKHR);
        uint32_t n = 0;
        CHECK(xrGetVulkanDeviceExtensionsKHR(instance, system, 0, &n, NULL));
        if (n > sizeof names_buf) FAIL("device extension list too long");
        CHECK(xrGetVulkanDeviceExtensionsKHR(instance, system, n, &n, names_buf));
        printf("runtime device extensions: %s%s\n", names_buf, ignore ? " (ignored)" : "");
        if (!ignore) {
            dci.enabledExtensionCount = split(names_buf, names, 64);
            dci.ppEnabledExtensionNames = names;
        }
        VK(vkCreateDevice(physical, &dci, NULL, &device));
    } else {
        PFN_xrCreateVulkanDeviceKHR xrCreateVulkanDeviceKHR = NULL;
        gipa(instance, "xrCreateVulkanDeviceKHR", (PFN_xrVoidFunction *)&xrCreateVulkanDeviceKHR);
        if (!xrCreateVulkanDeviceKHR) FAIL("no xrCreateVulkanDeviceKHR");
        XrVulkanDeviceCreateInfoKHR xdci = {XR_TYPE_VULKAN_DEVICE_CREATE_INFO_KHR, NULL, system, 0, vkGetInstanceProcAddr,
                                            physical, &dci, NULL};
        VkResult vr;
        CHECK(xrCreateVulkanDeviceKHR(instance, &xdci, &device, &vr));
        VK(vr);
    }
    vkGetDeviceQueue(device, family, 0, &queue);
    VkCommandPoolCreateInfo pci = {VK_STRUCTURE_TYPE_COMMAND_POOL_CREATE_INFO, NULL,
                                   VK_COMMAND_POOL_CREATE_RESET_COMMAND_BUFFER_BIT, family};
    VkCommandPool pool;
    VK(vkCreateCommandPool(device, &pci, NULL, &pool));
    VkCommandBufferAllocateInfo cai = {VK_STRUCTURE_TYPE_COMMAND_BUFFER_ALLOCATE_INFO, NULL, pool,
                                       VK_COMMAND_BUFFER_LEVEL_PRIMARY, 1};
    VK(vkAllocateCommandBuffers(device, &cai, &cmd));
    VkFenceCreateInfo fci = {VK_STRUCTURE_TYPE_FENCE_CREATE_INFO, NULL, 0};
    VK(vkCreateFence(device, &fci, NULL, &fence));
    printf("vulkan device\n");

    /* ---------------------------------------------------------------- session, space, swapchains */
    XrGraphicsBindingVulkanKHR binding = {XR_TYPE_GRAPHICS_BINDING_VULKAN_KHR, NULL, vk_instance, physical, device,
                                          family, 0};
    XrSessionCreateInfo sci = {XR_TYPE_SESSION_CREATE_INFO, &binding, 0, system};
    XrSession session;
    CHECK(xrCreateSession(instance, &sci, &session));
    printf("session\n");
    XrReferenceSpaceCreateInfo rsci = {XR_TYPE_REFERENCE_SPACE_CREATE_INFO, NULL, XR_REFERENCE_SPACE_TYPE_LOCAL,
                                       {{0, 0, 0, 1}, {0, 0, 0}}};
    XrSpace space;
    CHECK(xrCreateReferenceSpace(session, &rsci, &space));
    int sbs = getenv("APP_SIDE_BY_SIDE") != NULL;
    int nchains = sbs ? 1 : 2, CW = sbs ? 2 * W : W;
    if (sbs) formats[1] = formats[0];
    XrSwapchain chains[2];
    VkImage images[2][8];
    uint32_t counts[2];
    Buffer upload[2], readback[2];
    for (int e = 0; e < nchains; e++) {
        XrSwapchainCreateInfo info = {XR_TYPE_SWAPCHAIN_CREATE_INFO};
        info.usageFlags = XR_SWAPCHAIN_USAGE_COLOR_ATTACHMENT_BIT | XR_SWAPCHAIN_USAGE_TRANSFER_DST_BIT |
                          (check ? XR_SWAPCHAIN_USAGE_TRANSFER_SRC_BIT : 0);
        info.format = formats[e]->format;
        info.sampleCount = info.faceCount = info.arraySize = info.mipCount = 1;
        info.width = (uint32_t)CW;
        info.height = (uint32_t)H;
        CHECK(xrCreateSwapchain(session, &info, &chains[e]));
        XrSwapchainImageVulkanKHR imgs[8];
        for (int i = 0; i < 8; i++) imgs[i] = (XrSwapchainImageVulkanKHR){XR_TYPE_SWAPCHAIN_IMAGE_VULKAN_KHR};
        CHECK(xrEnumerateSwapchainImages(chains[e], 0, &counts[e], NULL));
        if (counts[e] > 8) FAIL("too many swapchain images");
        CHECK(xrEnumerateSwapchainImages(chains[e], counts[e], &counts[e], (XrSwapchainImageBaseHeader *)imgs));
        for (uint32_t i = 0; i < counts[e]; i++) images[e][i] = imgs[i].image;
    }
    /* each eye's picture in its swapchain's bytes (side by side: both in the one swapchain's format) */
    for (int e = 0; e < 2; e++) {
        int bpp = formats[e]->bpp;
        if (!host_buffer((VkDeviceSize)W * H * bpp, VK_BUFFER_USAGE_TRANSFER_SRC_BIT, &upload[e]) ||
            !host_buffer((VkDeviceSize)W * H * bpp, VK_BUFFER_USAGE_TRANSFER_DST_BIT, &readback[e]))
            FAIL("cannot make the upload and read-back buffers");
        convert(pictures[e], W, H, formats[e], gain, upload[e].mapped);
    }
    if (sbs) chains[1] = chains[0], counts[1] = counts[0], memcpy(images[1], images[0], sizeof images[0]);
    printf("swapchains %dx%d formats %s,%s\n", CW, H, formats[0]->name, formats[1]->name);

    /* ---------------------------------------------------------------- the frame loop */
    int running = 0, frames = 0, exit_requested = 0, done = 0;
    while (!done) {
        CHECK(follow_session(instance, session, xrPollEvent, xrBeginSession, xrEndSession, &running, &done));
        if (done || !running) continue;
        XrFrameState fs = {XR_TYPE_FRAME_STATE};
        CHECK(xrWaitFrame(session, NULL, &fs));
        CHECK(xrBeginFrame(session, NULL));
        XrCompositionLayerProjectionView pv[2];
        XrCompositionLayerProjection layer = {XR_TYPE_COMPOSITION_LAYER_PROJECTION};
        const XrCompositionLayerBaseHeader *list[1] = {(const XrCompositionLayerBaseHeader *)&layer};
        uint32_t released[2] = {0, 0};
        int submit = 0;
        if (fs.shouldRender && !exit_requested) {
            XrViewLocateInfo vli = {XR_TYPE_VIEW_LOCATE_INFO, NULL, XR_VIEW_CONFIGURATION_TYPE_PRIMARY_STEREO,
                                    fs.predictedDisplayTime, space};
            XrViewState vs = {XR_TYPE_VIEW_STATE};
            XrView views[2] = {{XR_TYPE_VIEW}, {XR_TYPE_VIEW}};
            uint32_t nviews = 0;
            CHECK(xrLocateViews(session, &vli, &vs, 2, &nviews, views));
            uint32_t index[2];
            for (int c = 0; c < nchains; c++) {
                CHECK(xrAcquireSwapchainImage(chains[c], NULL, &index[c]));
                XrSwapchainImageWaitInfo wi = {XR_TYPE_SWAPCHAIN_IMAGE_WAIT_INFO, NULL, XR_INFINITE_DURATION};
                CHECK(xrWaitSwapchainImage(chains[c], &wi));
            }
            begin_commands();
            for (int c = 0; c < nchains; c++)
                barrier(images[c][index[c]], VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL, VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                        VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT, VK_ACCESS_TRANSFER_WRITE_BIT);
            for (int e = 0; e < 2; e++) {
                int c = sbs ? 0 : e, x0 = sbs ? e * W : 0;
                VkBufferImageCopy region = {0, 0, 0, {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1}, {x0, 0, 0},
                                            {(uint32_t)W, (uint32_t)H, 1}};
                vkCmdCopyBufferToImage(cmd, upload[e].buffer, images[c][index[c]], VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL,
                                       1, &region);
                released[e] = index[c];
                pv[e] = (XrCompositionLayerProjectionView){XR_TYPE_COMPOSITION_LAYER_PROJECTION_VIEW};
                pv[e].pose = views[e].pose;
                pv[e].fov = views[e].fov;
                pv[e].subImage.swapchain = chains[c];
                pv[e].subImage.imageRect = (XrRect2Di){{x0 + rect[0], rect[1]}, {rect[2], rect[3]}};
            }
            for (int c = 0; c < nchains; c++)
                barrier(images[c][index[c]], VK_IMAGE_LAYOUT_TRANSFER_DST_OPTIMAL, VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL,
                        VK_ACCESS_TRANSFER_WRITE_BIT, VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT);
            if (!run_commands()) FAIL("uploading the pictures failed");
            for (int c = 0; c < nchains; c++) CHECK(xrReleaseSwapchainImage(chains[c], NULL));
            layer.space = space;
            layer.viewCount = 2;
            layer.views = pv;
            submit = 1;
        }
        XrFrameEndInfo fei = {XR_TYPE_FRAME_END_INFO, NULL, fs.predictedDisplayTime, XR_ENVIRONMENT_BLEND_MODE_OPAQUE,
                              submit ? 1u : 0u, list};
        CHECK(xrEndFrame(session, &fei));
        if (layer.views != pv && submit) FAIL("the frame description changed");
        if (submit && (pv[0].subImage.swapchain != chains[0] || pv[1].subImage.swapchain != chains[1]))
            FAIL("the application's projection views were written");
        if (submit && check) {          /* each eye's W x H part of its released image: exactly what was written */
            begin_commands();
            for (int e = 0; e < 2; e++) {
                int c = sbs ? 0 : e, x0 = sbs ? e * W : 0;
                VkImage image = images[c][released[e]];
                barrier(image, VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL,
                        VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT | VK_ACCESS_TRANSFER_WRITE_BIT, VK_ACCESS_TRANSFER_READ_BIT);
                VkBufferImageCopy region = {0, 0, 0, {VK_IMAGE_ASPECT_COLOR_BIT, 0, 0, 1}, {x0, 0, 0},
                                            {(uint32_t)W, (uint32_t)H, 1}};
                vkCmdCopyImageToBuffer(cmd, image, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, readback[e].buffer, 1, &region);
                barrier(image, VK_IMAGE_LAYOUT_TRANSFER_SRC_OPTIMAL, VK_IMAGE_LAYOUT_COLOR_ATTACHMENT_OPTIMAL,
                        VK_ACCESS_TRANSFER_READ_BIT, VK_ACCESS_COLOR_ATTACHMENT_WRITE_BIT);
            }
            if (!run_commands()) FAIL("reading the application's images back failed");
            for (int e = 0; e < 2; e++)
                if (memcmp(readback[e].mapped, upload[e].mapped, (size_t)W * H * formats[e]->bpp) != 0)
                    FAIL("the %s eye's swapchain image changed across xrEndFrame", e ? "right" : "left");
        }
        if (submit) {
            frames++;
            printf("frame %d\n", frames);
        }
        const char *stop = getenv("APP_STOP_FILE");
        if (stop) nanosleep(&(struct timespec){0, 20000000}, NULL);
        if (frames >= frames_wanted && !exit_requested && (!stop || access(stop, F_OK) == 0)) {
            CHECK(xrRequestExitSession(session));
            exit_requested = 1;
        }
    }
    if (check) printf("images checked unchanged after every frame\n");
    for (int c = 0; c < nchains; c++) CHECK(xrDestroySwapchain(chains[c]));
    CHECK(xrDestroySpace(space));
    CHECK(xrDestroySession(session));
    for (int e = 0; e < 2; e++) free_buffer(&upload[e]), free_buffer(&readback[e]);
    vkDestroyFence(device, fence, NULL);
    vkDestroyCommandPool(device, pool, NULL);
    vkDestroyDevice(device, NULL);
    vkDestroyInstance(vk_instance, NULL);
    CHECK(xrDestroyInstance(instance));
    printf("done %d frames\n", frames);
    free(pictures[0]);
    free(pictures[1]);
    return 0;
}
