/* A small OpenXR OpenGL application for vrcorrect's layer tests (test equipment; it knows nothing
 * of vrcorrect). It opens an Xlib window with a GLX 4.5 core context, loads the OpenXR loader named
 * by APP_LOADER (pyopenxr's libopenxr_loader.so), runs one session with XR_KHR_opengl_enable and
 * submits, for each eye, a known image (raw RGBA8 bytes, GL row order: bottom row first) from
 * APP_IMAGE_LEFT / APP_IMAGE_RIGHT into its own swapchains, every frame, until APP_FRAMES frames
 * were submitted; then it asks to exit and tears everything down.
 *
 * Environment:
 *   APP_LOADER        path of libopenxr_loader.so (required)
 *   APP_IMAGE_LEFT    raw image of the left eye (W*H*4 bytes, W x H the runtime's view size)
 *   APP_IMAGE_RIGHT   the right eye's
 *   APP_FRAMES        frames to submit (default 3)
 *   APP_FORMAT        the swapchains' format, or "LEFT,RIGHT" for one each: "srgb" (GL_SRGB8_ALPHA8, default),
 *                     "rgba8" (GL_RGBA8), "rgb10a2" (GL_RGB10_A2), "rgba16f" (GL_RGBA16F), "rgba16" (GL_RGBA16);
 *                     the picture's bytes are uploaded as GL_UNSIGNED_BYTE (GL converts them)
 *   APP_GAIN          "g": the half-float swapchains get the picture as floats v / 255 * g instead (above 1 for
 *                     g > 1, as HDR rendering gives); alpha 1
 *   APP_RECT          "x,y,w,h": submit this imageRect (GL pixels from the bottom left) instead of all
 *   APP_LAYERS        comma-separated API layer names to enable in xrCreateInstance
 *   APP_OUT_DIR       after each frame, write the app's own released images there as
 *                     app_NNNNN_view_V.raw (W*H*4 bytes, GL row order) to prove they are untouched
 *   APP_SCISSOR       "1": leave GL_SCISSOR_TEST on (a small box) at xrEndFrame, as a careless app might
 *   APP_BINDING       "d3d11": ask for a session with an (empty) XrGraphicsBindingD3D11KHR instead of the
 *                     GLX binding, as a Direct3D 11 application would; exits 3 when xrCreateSession fails
 *   APP_CHECK         "1": after each xrEndFrame read each eye's released image back in the type it was uploaded
 *                     in and fail unless it holds exactly that
 *   APP_SIDE_BY_SIDE  "1": one swapchain twice as wide, the left eye's picture and view in its left half
 *   APP_STOP_FILE     run until this file exists (then at least APP_FRAMES frames), 20 ms a frame
 * Prints one line per step to stdout; exit status 0 when the session life cycle completed.
 */
#define _GNU_SOURCE
#include <dlfcn.h>
#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>
#include <time.h>
#include <unistd.h>

#include <X11/Xlib.h>
#define GL_GLEXT_PROTOTYPES
#include <GL/gl.h>
#include <GL/glx.h>
#define XR_USE_GRAPHICS_API_OPENGL
#define XR_USE_PLATFORM_XLIB
#include <openxr/openxr.h>
#include <openxr/openxr_platform.h>

#include "../xr_app_common.h"

static PFN_xrGetInstanceProcAddr gipa;
static XrInstance instance;

#define FAIL(...) do { fprintf(stderr, "xr_gl_app: " __VA_ARGS__); fputc('\n', stderr); return 1; } while (0)
#define CHECK(call) do { XrResult r_ = (call); if (XR_FAILED(r_)) FAIL("%s failed: %d", #call, r_); } while (0)
#define FN(name) PFN_##name name = NULL; gipa(instance, #name, (PFN_xrVoidFunction *)&name); \
    if (!name) FAIL("no %s", #name)

typedef GLXContext (*CreateContextAttribs)(Display *, GLXFBConfig, GLXContext, Bool, const int *);

static int64_t format_named(const char *name, size_t n) {
    static const struct { const char *name; int64_t format; } names[] = {
        {"srgb", GL_SRGB8_ALPHA8}, {"rgba8", GL_RGBA8}, {"rgb10a2", GL_RGB10_A2}, {"rgba16f", GL_RGBA16F},
        {"rgba16", GL_RGBA16}};
    for (size_t i = 0; i < sizeof names / sizeof names[0]; i++)
        if (strlen(names[i].name) == n && strncmp(names[i].name, name, n) == 0) return names[i].format;
    return 0;
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
    int64_t formats[2] = {GL_SRGB8_ALPHA8, GL_SRGB8_ALPHA8};
    if (getenv("APP_FORMAT")) {
        const char *spec = getenv("APP_FORMAT"), *comma = strchr(spec, ',');
        formats[0] = format_named(spec, comma ? (size_t)(comma - spec) : strlen(spec));
        formats[1] = comma ? format_named(comma + 1, strlen(comma + 1)) : formats[0];
        if (!formats[0] || !formats[1]) FAIL("APP_FORMAT: unknown format in %s", spec);
    }
    float gain = getenv("APP_GAIN") ? (float)atof(getenv("APP_GAIN")) : 0.0f;
    int check = getenv("APP_CHECK") != NULL;

    /* ---------------------------------------------------------------- GL: window and 4.5 core context */
    Display *dpy = XOpenDisplay(NULL);
    if (!dpy) FAIL("no X display");
    int attribs[] = {GLX_X_RENDERABLE, True, GLX_DRAWABLE_TYPE, GLX_WINDOW_BIT, GLX_RENDER_TYPE, GLX_RGBA_BIT,
                     GLX_RED_SIZE, 8, GLX_GREEN_SIZE, 8, GLX_BLUE_SIZE, 8, GLX_ALPHA_SIZE, 8, GLX_DOUBLEBUFFER, True, None};
    int n = 0;
    GLXFBConfig *configs = glXChooseFBConfig(dpy, DefaultScreen(dpy), attribs, &n);
    if (!configs || n < 1) FAIL("no GLX frame buffer configuration");
    GLXFBConfig config = configs[0];
    XFree(configs);
    XVisualInfo *vi = glXGetVisualFromFBConfig(dpy, config);
    XSetWindowAttributes swa = {0};
    swa.colormap = XCreateColormap(dpy, RootWindow(dpy, vi->screen), vi->visual, AllocNone);
    Window win = XCreateWindow(dpy, RootWindow(dpy, vi->screen), 0, 0, 64, 64, 0, vi->depth, InputOutput, vi->visual,
                               CWColormap, &swa);
    CreateContextAttribs create = (CreateContextAttribs)glXGetProcAddressARB((const GLubyte *)"glXCreateContextAttribsARB");
    int ctx_attribs[] = {0x2091, 4, 0x2092, 5, 0x9126, 0x1, None}; /* major 4, minor 5, core profile */
    GLXContext ctx = create ? create(dpy, config, NULL, True, ctx_attribs) : NULL;
    if (!ctx) FAIL("no OpenGL 4.5 core context");
    if (!glXMakeCurrent(dpy, win, ctx)) FAIL("glXMakeCurrent failed");
    printf("gl %s\n", glGetString(GL_VERSION));

    /* ---------------------------------------------------------------- instance, system */
    const char *extensions[] = {XR_KHR_OPENGL_ENABLE_EXTENSION_NAME};
    char layer_buf[1024] = "";
    const char *layers[8];
    uint32_t nlayers = 0;
    if (getenv("APP_LAYERS")) {
        snprintf(layer_buf, sizeof layer_buf, "%s", getenv("APP_LAYERS"));
        for (char *tok = strtok(layer_buf, ","); tok && nlayers < 8; tok = strtok(NULL, ",")) layers[nlayers++] = tok;
    }
    XrInstanceCreateInfo ici = {XR_TYPE_INSTANCE_CREATE_INFO};
    snprintf(ici.applicationInfo.applicationName, XR_MAX_APPLICATION_NAME_SIZE, "xr_gl_app");
    ici.applicationInfo.apiVersion = XR_MAKE_VERSION(1, 0, 0);
    ici.enabledExtensionCount = 1;
    ici.enabledExtensionNames = extensions;
    ici.enabledApiLayerCount = nlayers;
    ici.enabledApiLayerNames = layers;
    PFN_xrCreateInstance xrCreateInstance_ = NULL;
    gipa(XR_NULL_HANDLE, "xrCreateInstance", (PFN_xrVoidFunction *)&xrCreateInstance_);
    if (!xrCreateInstance_) FAIL("no xrCreateInstance");
    CHECK(xrCreateInstance_(&ici, &instance));
    printf("instance\n");
    FN(xrGetSystem); FN(xrGetOpenGLGraphicsRequirementsKHR); FN(xrEnumerateViewConfigurationViews);
    FN(xrCreateSession); FN(xrDestroySession); FN(xrCreateReferenceSpace); FN(xrDestroySpace);
    FN(xrCreateSwapchain); FN(xrDestroySwapchain); FN(xrEnumerateSwapchainImages); FN(xrAcquireSwapchainImage);
    FN(xrWaitSwapchainImage); FN(xrReleaseSwapchainImage); FN(xrPollEvent); FN(xrBeginSession); FN(xrEndSession);
    FN(xrRequestExitSession); FN(xrWaitFrame); FN(xrBeginFrame); FN(xrEndFrame); FN(xrLocateViews);
    FN(xrDestroyInstance);
    XrSystemGetInfo sgi = {XR_TYPE_SYSTEM_GET_INFO, NULL, XR_FORM_FACTOR_HEAD_MOUNTED_DISPLAY};
    XrSystemId system;
    CHECK(xrGetSystem(instance, &sgi, &system));
    XrGraphicsRequirementsOpenGLKHR req = {XR_TYPE_GRAPHICS_REQUIREMENTS_OPENGL_KHR};
    CHECK(xrGetOpenGLGraphicsRequirementsKHR(instance, system, &req));
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

    /* ---------------------------------------------------------------- session, space, swapchains */
    XrGraphicsBindingOpenGLXlibKHR binding = {XR_TYPE_GRAPHICS_BINDING_OPENGL_XLIB_KHR};
    binding.xDisplay = dpy;
    binding.visualid = (uint32_t)vi->visualid;
    binding.glxFBConfig = config;
    binding.glxDrawable = win;
    binding.glxContext = ctx;
    XrSessionCreateInfo sci = {XR_TYPE_SESSION_CREATE_INFO, &binding, 0, system};
    XrSession session;
    if (getenv("APP_BINDING") && strcmp(getenv("APP_BINDING"), "d3d11") == 0) {
        /* XrGraphicsBindingD3D11KHR's type and next, its device pointer zero: this application has no D3D device */
        struct { XrStructureType type; const void *next; void *device; } d3d = {(XrStructureType)1000027000, NULL, NULL};
        sci.next = &d3d;
        XrResult r = xrCreateSession(instance, &sci, &session);
        printf("d3d11 create_session %d\n", (int)r);
        if (XR_FAILED(r)) {
            xrDestroyInstance(instance);
            return 3;
        }
    } else {
        CHECK(xrCreateSession(instance, &sci, &session));
    }
    printf("session\n");
    XrReferenceSpaceCreateInfo rsci = {XR_TYPE_REFERENCE_SPACE_CREATE_INFO, NULL, XR_REFERENCE_SPACE_TYPE_LOCAL,
                                       {{0, 0, 0, 1}, {0, 0, 0}}};
    XrSpace space;
    CHECK(xrCreateReferenceSpace(session, &rsci, &space));
    int sbs = getenv("APP_SIDE_BY_SIDE") != NULL;
    int nchains = sbs ? 1 : 2, CW = sbs ? 2 * W : W;      /* swapchains and their width */
    XrSwapchain chains[2];
    GLuint images[2][8];
    uint32_t counts[2];
    for (int e = 0; e < nchains; e++) {
        XrSwapchainCreateInfo info = {XR_TYPE_SWAPCHAIN_CREATE_INFO};
        info.usageFlags = XR_SWAPCHAIN_USAGE_COLOR_ATTACHMENT_BIT | XR_SWAPCHAIN_USAGE_SAMPLED_BIT;
        info.format = formats[e];
        info.sampleCount = info.faceCount = info.arraySize = info.mipCount = 1;
        info.width = (uint32_t)CW;
        info.height = (uint32_t)H;
        CHECK(xrCreateSwapchain(session, &info, &chains[e]));
        XrSwapchainImageOpenGLKHR imgs[8];
        for (int i = 0; i < 8; i++) imgs[i] = (XrSwapchainImageOpenGLKHR){XR_TYPE_SWAPCHAIN_IMAGE_OPENGL_KHR};
        CHECK(xrEnumerateSwapchainImages(chains[e], 0, &counts[e], NULL));
        if (counts[e] > 8) FAIL("too many swapchain images");
        CHECK(xrEnumerateSwapchainImages(chains[e], counts[e], &counts[e], (XrSwapchainImageBaseHeader *)imgs));
        for (uint32_t i = 0; i < counts[e]; i++) images[e][i] = imgs[i].image;
    }
    if (sbs) chains[1] = chains[0], images[1][0] = images[0][0], counts[1] = counts[0];
    if (sbs) formats[1] = formats[0];
    printf("swapchains %dx%d formats 0x%llx,0x%llx\n", CW, H, (unsigned long long)formats[0],
           (unsigned long long)formats[1]);
    /* with a gain, the half-float swapchains get floats: v / 255 * gain, alpha 1 */
    float *floats[2] = {NULL, NULL};
    for (int e = 0; e < 2; e++) {
        if (!gain || formats[e] != GL_RGBA16F) continue;
        floats[e] = malloc(bytes * sizeof(float));
        for (size_t i = 0; i < bytes; i++) floats[e][i] = i % 4 == 3 ? 1.0f : pictures[e][i] / 255.0f * gain;
    }
    float *readback_floats = malloc(bytes * sizeof(float) * (size_t)(sbs ? 2 : 1));

    /* ---------------------------------------------------------------- the frame loop */
    int running = 0, frames = 0, exit_requested = 0, done = 0;
    const char *out_dir = getenv("APP_OUT_DIR");
    unsigned char *readback = malloc(bytes * (size_t)(sbs ? 2 : 1));
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
            for (int e = 0; e < 2; e++) {
                int c = sbs ? 0 : e, x0 = sbs ? e * W : 0;
                glBindTexture(GL_TEXTURE_2D, images[c][index[c]]);
                glPixelStorei(GL_UNPACK_ALIGNMENT, 1);
                if (floats[e]) glTexSubImage2D(GL_TEXTURE_2D, 0, x0, 0, W, H, GL_RGBA, GL_FLOAT, floats[e]);
                else glTexSubImage2D(GL_TEXTURE_2D, 0, x0, 0, W, H, GL_RGBA, GL_UNSIGNED_BYTE, pictures[e]);
                glBindTexture(GL_TEXTURE_2D, 0);
                released[e] = index[c];
                pv[e] = (XrCompositionLayerProjectionView){XR_TYPE_COMPOSITION_LAYER_PROJECTION_VIEW};
                pv[e].pose = views[e].pose;
                pv[e].fov = views[e].fov;
                pv[e].subImage.swapchain = chains[c];
                pv[e].subImage.imageRect = (XrRect2Di){{x0 + rect[0], rect[1]}, {rect[2], rect[3]}};
            }
            for (int c = 0; c < nchains; c++) CHECK(xrReleaseSwapchainImage(chains[c], NULL));
            layer.space = space;
            layer.viewCount = 2;
            layer.views = pv;
            submit = 1;
        }
        if (getenv("APP_SCISSOR")) {
            glEnable(GL_SCISSOR_TEST);
            glScissor(0, 0, 2, 2);
        }
        XrFrameEndInfo fei = {XR_TYPE_FRAME_END_INFO, NULL, fs.predictedDisplayTime, XR_ENVIRONMENT_BLEND_MODE_OPAQUE,
                              submit ? 1u : 0u, list};
        CHECK(xrEndFrame(session, &fei));
        if (getenv("APP_SCISSOR")) {
            GLboolean still = glIsEnabled(GL_SCISSOR_TEST);
            GLint box[4];
            glGetIntegerv(GL_SCISSOR_BOX, box);
            if (!still || box[2] != 2 || box[3] != 2) FAIL("GL state changed across xrEndFrame (scissor)");
            glDisable(GL_SCISSOR_TEST);
        }
        if (layer.views != pv && submit) FAIL("the frame description changed");
        if (submit && (pv[0].subImage.swapchain != chains[0] || pv[1].subImage.swapchain != chains[1]))
            FAIL("the application's projection views were written");
        for (int e = 0; e < 2 && submit && check; e++) {   /* each eye's image: exactly what was uploaded */
            int c = sbs ? 0 : e, x0 = sbs ? e * W : 0;
            glBindTexture(GL_TEXTURE_2D, images[c][released[e]]);
            glPixelStorei(GL_PACK_ALIGNMENT, 1);
            if (floats[e]) glGetTexImage(GL_TEXTURE_2D, 0, GL_RGBA, GL_FLOAT, readback_floats);
            else glGetTexImage(GL_TEXTURE_2D, 0, GL_RGBA, GL_UNSIGNED_BYTE, readback);
            glBindTexture(GL_TEXTURE_2D, 0);
            for (int y = 0; y < H; y++) {
                size_t at = ((size_t)y * CW + x0) * 4, row = (size_t)y * W * 4, n = (size_t)W * 4;
                /* a half float holds v / 255 * gain to within 2^-11 of it: compared as such */
                for (size_t i = 0; floats[e] && i < n; i++)
                    if (fabsf(readback_floats[at + i] - floats[e][row + i]) > 1e-3f * (1.0f + fabsf(floats[e][row + i])))
                        FAIL("the %s eye's swapchain image changed across xrEndFrame", e ? "right" : "left");
                if (!floats[e] && memcmp(readback + at, pictures[e] + row, n) != 0)
                    FAIL("the %s eye's swapchain image changed across xrEndFrame", e ? "right" : "left");
            }
        }
        if (submit) {
            for (int e = 0; e < 2 && out_dir; e++) {   /* each eye's W x H part of its swapchain image */
                int c = sbs ? 0 : e, x0 = sbs ? e * W : 0;
                glBindTexture(GL_TEXTURE_2D, images[c][released[e]]);
                glPixelStorei(GL_PACK_ALIGNMENT, 1);
                glGetTexImage(GL_TEXTURE_2D, 0, GL_RGBA, GL_UNSIGNED_BYTE, readback);
                glBindTexture(GL_TEXTURE_2D, 0);
                char path[1200];
                snprintf(path, sizeof path, "%s/app_%05d_view_%d.raw", out_dir, frames, e);
                FILE *f = fopen(path, "wb");
                for (int y = 0; f && y < H; y++)
                    fwrite(readback + ((size_t)y * CW + x0) * 4, 1, (size_t)W * 4, f);
                if (f) fclose(f);
            }
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
    GLenum err = glGetError();
    printf("gl error 0x%x\n", err);
    for (int c = 0; c < nchains; c++) CHECK(xrDestroySwapchain(chains[c]));
    CHECK(xrDestroySpace(space));
    CHECK(xrDestroySession(session));
    CHECK(xrDestroyInstance(instance));
    if (check) printf("images checked unchanged after every frame\n");
    printf("done %d frames\n", frames);
    glXMakeCurrent(dpy, None, NULL);
    glXDestroyContext(dpy, ctx);
    XDestroyWindow(dpy, win);
    XCloseDisplay(dpy);
    free(readback);
    free(readback_floats);
    free(floats[0]);
    free(floats[1]);
    free(pictures[0]);
    free(pictures[1]);
    return 0;
}
