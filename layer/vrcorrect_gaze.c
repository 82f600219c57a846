/* vrcorrect's OpenXR API layer: the gaze from an eye tracker (XR_EXT_eye_gaze_interaction), for a
 * foveated correction (a window around the gaze; vrcorrect.runtime.strategies.foveated).
 *
 * Only when the layer's configuration asks for a fovea ("fovea_deg" in layer.json) does the layer
 * ask for the eye tracker:
 *   - xrCreateInstance: the extension is added to the application's list. A runtime that lacks it
 *     answers XR_ERROR_EXTENSION_NOT_PRESENT; the layer then creates the instance with the
 *     application's list alone and says so once in the log (the window stays at the configured gaze).
 *   - The layer's own action set ("vrcorrect_layer_gaze", one pose action bound to
 *     /user/eyes_ext/input/gaze_ext/pose of /interaction_profiles/ext/eye_gaze_interaction) lives beside
 *     the application's. The application's bindings are never changed: when the application suggests
 *     bindings for the eye-gaze profile itself, the layer's binding is added to its list (a later
 *     suggestion for a profile replaces the earlier one, so they go down together).
 *   - xrAttachSessionActionSets: the layer's set is attached with the application's (if the runtime
 *     refuses the longer list, the application's list goes down alone and the layer logs it).
 *     An application that attaches no action sets gets no tracked gaze (logged once).
 *   - xrSyncActions: the layer's set is added to the application's active sets.
 *   - xrEndFrame: the gaze action's space is located in each projection layer's space at the frame's
 *     display time, turned into each view's frame and projected through the view's field of view:
 *     (u, v), the gaze's place in the view's imageRect, 0..1 from its left and top edges. The engine
 *     (Engine.look) places the window there; NaN when the tracker gives no gaze this frame.
 */
#include "vrcorrect_layer.h"

#include <math.h>
#include <stdio.h>
#include <stdlib.h>
#include <string.h>

#define GAZE_PROFILE "/interaction_profiles/ext/eye_gaze_interaction"
#define GAZE_POSE "/user/eyes_ext/input/gaze_ext/pose"
#define GAZE_SET "vrcorrect_layer_gaze"
#define MAX_EXTENSIONS 64
#define MAX_BINDINGS 64
#define MAX_SETS 32

static struct {
    int wanted;                  /* the configuration asks for a fovea */
    int enabled;                 /* the instance has XR_EXT_eye_gaze_interaction */
    int attached;                /* the layer's set is attached to `session` */
    int said_unattached;
    XrSession session;
    XrActionSet set;
    XrAction action;
    XrSpace space;
    XrPath profile, pose;
    PFN_xrStringToPath StringToPath;
    PFN_xrCreateActionSet CreateActionSet;
    PFN_xrDestroyActionSet DestroyActionSet;
    PFN_xrCreateAction CreateAction;
    PFN_xrSuggestInteractionProfileBindings SuggestInteractionProfileBindings;
    PFN_xrAttachSessionActionSets AttachSessionActionSets;
    PFN_xrSyncActions SyncActions;
    PFN_xrCreateActionSpace CreateActionSpace;
    PFN_xrDestroySpace DestroySpace;
    PFN_xrLocateSpace LocateSpace;
    PFN_xrGetActionStatePose GetActionStatePose;
} G;

/* The layer configuration file, as vrcorrect.runtime.layer.config.config_path finds it. */
static void config_file(char *out, size_t size) {
    const char *named = getenv("VRCORRECT_LAYER_CONFIG");
    const char *xdg = getenv("XDG_CONFIG_HOME");
    const char *home = getenv("HOME");
    if (named && *named) snprintf(out, size, "%s", named);
    else if (xdg && *xdg) snprintf(out, size, "%s/vrcorrect/layer.json", xdg);
    else snprintf(out, size, "%s/.config/vrcorrect/layer.json", home ? home : "");
}

/* Whether the configuration names a fovea: a "fovea_deg" key whose value is not null (the engine
 * validates the file; this only decides whether to ask the runtime for the eye tracker). */
static int fovea_configured(void) {
    char path[1024];
    config_file(path, sizeof path);
    FILE *f = fopen(path, "rb");
    if (!f) return 0;
    char text[65536];
    size_t n = fread(text, 1, sizeof text - 1, f);
    fclose(f);
    text[n] = 0;
    const char *key = strstr(text, "\"fovea_deg\"");
    if (!key) return 0;
    const char *p = key + strlen("\"fovea_deg\"");
    while (*p == ' ' || *p == '\t' || *p == '\r' || *p == '\n' || *p == ':') p++;
    return *p && strncmp(p, "null", 4) != 0;
}

XrResult gaze_create_instance(const XrInstanceCreateInfo *info, XrResult (*down)(const XrInstanceCreateInfo *, void *),
                              void *context) {
    memset(&G, 0, sizeof G);
    G.wanted = info && fovea_configured();
    int has = 0;
    for (uint32_t i = 0; info && i < info->enabledExtensionCount; i++)
        has |= strcmp(info->enabledExtensionNames[i], XR_EXT_EYE_GAZE_INTERACTION_EXTENSION_NAME) == 0;
    if (!G.wanted || has || info->enabledExtensionCount >= MAX_EXTENSIONS) {
        XrResult r = down(info, context);
        G.enabled = XR_SUCCEEDED(r) && has;
        return r;
    }
    const char *names[MAX_EXTENSIONS + 1];
    for (uint32_t i = 0; i < info->enabledExtensionCount; i++) names[i] = info->enabledExtensionNames[i];
    names[info->enabledExtensionCount] = XR_EXT_EYE_GAZE_INTERACTION_EXTENSION_NAME;
    XrInstanceCreateInfo with = *info;
    with.enabledExtensionCount = info->enabledExtensionCount + 1;
    with.enabledExtensionNames = names;
    XrResult r = down(&with, context);
    if (r == XR_ERROR_EXTENSION_NOT_PRESENT) {
        layer_log("gaze: the runtime offers no eye tracker (XR_EXT_eye_gaze_interaction): the fovea's window "
                  "stays at the configured gaze");
        return down(info, context);
    }
    G.enabled = XR_SUCCEEDED(r);
    return r;
}

/* The layer's action set, action and binding; after the instance is made (L.next_gipa set). */
void gaze_start(XrInstance instance) {
    if (!G.enabled) return;
#define NEXT(n) if (XR_FAILED(L.next_gipa(instance, "xr" #n, (PFN_xrVoidFunction *)&G.n))) G.n = NULL;
    NEXT(StringToPath) NEXT(CreateActionSet) NEXT(DestroyActionSet) NEXT(CreateAction)
    NEXT(SuggestInteractionProfileBindings) NEXT(AttachSessionActionSets) NEXT(SyncActions) NEXT(CreateActionSpace)
    NEXT(DestroySpace) NEXT(LocateSpace) NEXT(GetActionStatePose)
#undef NEXT
    if (!G.StringToPath || !G.CreateActionSet || !G.CreateAction || !G.SuggestInteractionProfileBindings ||
        !G.AttachSessionActionSets || !G.SyncActions || !G.CreateActionSpace || !G.LocateSpace ||
        !G.GetActionStatePose || !G.DestroySpace || !G.DestroyActionSet) {
        layer_log("gaze: the runtime lacks an action function; the fovea's window stays at the configured gaze");
        G.enabled = 0;
        return;
    }
    XrActionSetCreateInfo si = {XR_TYPE_ACTION_SET_CREATE_INFO, NULL, GAZE_SET, "vrcorrect layer: eye gaze", 0};
    XrActionCreateInfo ai = {XR_TYPE_ACTION_CREATE_INFO, NULL, "gaze", XR_ACTION_TYPE_POSE_INPUT, 0, NULL,
                             "vrcorrect layer: eye gaze"};
    XrResult r = G.StringToPath(instance, GAZE_PROFILE, &G.profile);
    if (XR_SUCCEEDED(r)) r = G.StringToPath(instance, GAZE_POSE, &G.pose);
    if (XR_SUCCEEDED(r)) r = G.CreateActionSet(instance, &si, &G.set);
    if (XR_SUCCEEDED(r)) r = G.CreateAction(G.set, &ai, &G.action);
    XrActionSuggestedBinding mine = {G.action, G.pose};
    XrInteractionProfileSuggestedBinding sb = {XR_TYPE_INTERACTION_PROFILE_SUGGESTED_BINDING, NULL, G.profile, 1, &mine};
    if (XR_SUCCEEDED(r)) r = G.SuggestInteractionProfileBindings(instance, &sb);
    if (XR_FAILED(r)) {
        layer_log("gaze: the eye tracker's action could not be made (XrResult %d); the fovea's window stays at the "
                  "configured gaze", (int)r);
        if (G.set != XR_NULL_HANDLE) G.DestroyActionSet(G.set);
        G.set = XR_NULL_HANDLE;
        G.enabled = 0;
        return;
    }
    layer_log("gaze: asked the runtime for the eye tracker (XR_EXT_eye_gaze_interaction)");
}

static XrResult XRAPI_CALL gaze_SuggestInteractionProfileBindings(XrInstance instance,
                                                                   const XrInteractionProfileSuggestedBinding *info) {
    if (!G.enabled || !info || info->interactionProfile != G.profile || info->countSuggestedBindings >= MAX_BINDINGS)
        return G.SuggestInteractionProfileBindings(instance, info);
    XrActionSuggestedBinding all[MAX_BINDINGS + 1];
    for (uint32_t i = 0; i < info->countSuggestedBindings; i++) all[i] = info->suggestedBindings[i];
    all[info->countSuggestedBindings] = (XrActionSuggestedBinding){G.action, G.pose};
    XrInteractionProfileSuggestedBinding with = *info;
    with.countSuggestedBindings = info->countSuggestedBindings + 1;
    with.suggestedBindings = all;
    XrResult r = G.SuggestInteractionProfileBindings(instance, &with);
    if (XR_FAILED(r)) return G.SuggestInteractionProfileBindings(instance, info);    /* the application's answer */
    return r;
}

static XrResult XRAPI_CALL gaze_AttachSessionActionSets(XrSession session, const XrSessionActionSetsAttachInfo *info) {
    if (!G.enabled || session != L.session || !info || info->countActionSets >= MAX_SETS)
        return G.AttachSessionActionSets(session, info);
    XrActionSet sets[MAX_SETS + 1];
    for (uint32_t i = 0; i < info->countActionSets; i++) sets[i] = info->actionSets[i];
    sets[info->countActionSets] = G.set;
    XrSessionActionSetsAttachInfo with = *info;
    with.countActionSets = info->countActionSets + 1;
    with.actionSets = sets;
    XrResult r = G.AttachSessionActionSets(session, &with);
    if (XR_FAILED(r)) {
        layer_log("gaze: the runtime refused the eye tracker's action set beside the application's (XrResult %d); "
                  "the fovea's window stays at the configured gaze", (int)r);
        return G.AttachSessionActionSets(session, info);
    }
    XrActionSpaceCreateInfo ci = {XR_TYPE_ACTION_SPACE_CREATE_INFO, NULL, G.action, XR_NULL_PATH,
                                  {{0, 0, 0, 1}, {0, 0, 0}}};
    if (XR_FAILED(G.CreateActionSpace(session, &ci, &G.space))) {
        layer_log("gaze: the eye tracker's space could not be made; the fovea's window stays at the configured gaze");
        G.space = XR_NULL_HANDLE;
        return r;
    }
    G.attached = 1;
    G.session = session;
    return r;
}

static XrResult XRAPI_CALL gaze_SyncActions(XrSession session, const XrActionsSyncInfo *info) {
    if (!G.attached || session != G.session || !info || info->countActiveActionSets >= MAX_SETS)
        return G.SyncActions(session, info);
    XrActiveActionSet sets[MAX_SETS + 1];
    for (uint32_t i = 0; i < info->countActiveActionSets; i++) sets[i] = info->activeActionSets[i];
    sets[info->countActiveActionSets] = (XrActiveActionSet){G.set, XR_NULL_PATH};
    XrActionsSyncInfo with = *info;
    with.countActiveActionSets = info->countActiveActionSets + 1;
    with.activeActionSets = sets;
    XrResult r = G.SyncActions(session, &with);
    return XR_FAILED(r) ? G.SyncActions(session, info) : r;
}

PFN_xrVoidFunction gaze_hook(const char *name) {
    if (!G.enabled) return NULL;
    if (strcmp(name, "xrSuggestInteractionProfileBindings") == 0)
        return (PFN_xrVoidFunction)gaze_SuggestInteractionProfileBindings;
    if (strcmp(name, "xrAttachSessionActionSets") == 0) return (PFN_xrVoidFunction)gaze_AttachSessionActionSets;
    if (strcmp(name, "xrSyncActions") == 0) return (PFN_xrVoidFunction)gaze_SyncActions;
    return NULL;
}

/* v rotated by the unit quaternion q (x, y, z, w), or by its inverse. */
static void rotate(XrQuaternionf q, const double v[3], int inverse, double out[3]) {
    double qx = inverse ? -q.x : q.x, qy = inverse ? -q.y : q.y, qz = inverse ? -q.z : q.z, qw = q.w;
    double tx = 2 * (qy * v[2] - qz * v[1]), ty = 2 * (qz * v[0] - qx * v[2]), tz = 2 * (qx * v[1] - qy * v[0]);
    out[0] = v[0] + qw * tx + (qy * tz - qz * ty);
    out[1] = v[1] + qw * ty + (qz * tx - qx * tz);
    out[2] = v[2] + qw * tz + (qx * ty - qy * tx);
}

/* Tells the engine where each view's gaze lies (Engine.look), under the GIL. */
void gaze_views(const XrFrameEndInfo *info, const FrameView *views, uint32_t nviews) {
    if (!G.wanted) return;
    if (G.enabled && !G.attached && !G.said_unattached) {
        layer_log("gaze: the application attached no action sets, so the layer cannot read the eye tracker; the "
                  "fovea's window stays at the configured gaze");
        G.said_unattached = 1;
    }
    int active = 0;
    if (G.attached) {
        XrActionStateGetInfo gi = {XR_TYPE_ACTION_STATE_GET_INFO, NULL, G.action, XR_NULL_PATH};
        XrActionStatePose state = {XR_TYPE_ACTION_STATE_POSE, NULL, XR_FALSE};
        active = XR_SUCCEEDED(G.GetActionStatePose(G.session, &gi, &state)) && state.isActive;
    }
    for (uint32_t i = 0; i < nviews; i++) {
        const FrameView *f = &views[i];
        const XrCompositionLayerProjection *p = (const XrCompositionLayerProjection *)info->layers[f->layer];
        double u = NAN, v = NAN;
        XrSpaceLocation loc = {XR_TYPE_SPACE_LOCATION, NULL, 0, {{0, 0, 0, 1}, {0, 0, 0}}};
        const XrSpaceLocationFlags need = XR_SPACE_LOCATION_ORIENTATION_VALID_BIT;
        if (active && XR_SUCCEEDED(G.LocateSpace(G.space, p->space, info->displayTime, &loc)) &&
            (loc.locationFlags & need) == need) {
            const XrCompositionLayerProjectionView *pv = &p->views[f->view];
            double forward[3] = {0, 0, -1}, in_space[3], d[3];
            rotate(loc.pose.orientation, forward, 0, in_space);
            rotate(pv->pose.orientation, in_space, 1, d);         /* the gaze in the view's frame */
            if (d[2] < -1e-6) {                                     /* in front of the eye */
                double tx = d[0] / -d[2], ty = d[1] / -d[2];
                double l = tan(pv->fov.angleLeft), r = tan(pv->fov.angleRight);
                double up = tan(pv->fov.angleUp), dn = tan(pv->fov.angleDown);
                if (r - l > 1e-9 && up - dn > 1e-9) {
                    u = (tx - l) / (r - l);
                    v = (up - ty) / (up - dn);
                }
            }
        }
        PyObject *res = engine_call("look", "(Idd)", f->view, u, v);
        Py_XDECREF(res);
    }
}

void gaze_session_end(XrSession session) {
    if (session != G.session || G.space == XR_NULL_HANDLE) return;
    G.DestroySpace(G.space);
    G.space = XR_NULL_HANDLE;
    G.attached = 0;
    G.session = XR_NULL_HANDLE;
}
