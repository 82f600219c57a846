/* What the tests' two OpenXR applications (xr_gl_app/xr_gl_app.c, xr_vk_app/xr_vk_app.c) share:
 * reading a raw picture and following the session's state changes. Test equipment. Include after
 * <openxr/openxr.h>. */
#ifndef XR_APP_COMMON_H
#define XR_APP_COMMON_H

#include <stdio.h>
#include <stdlib.h>

/* `size` bytes of the file at `path` (malloc'd), or NULL */
static unsigned char *read_raw(const char *path, size_t size) {
    if (!path) return NULL;
    FILE *f = fopen(path, "rb");
    if (!f) return NULL;
    unsigned char *data = malloc(size);
    if (data && fread(data, 1, size, f) != size) { free(data); data = NULL; }
    fclose(f);
    return data;
}

/* Handles the pending events (one "state N" line each on stdout): begins the session (stereo) at
 * READY, ends it at STOPPING, sets *done at EXITING or LOSS_PENDING. Returns the first failed call's
 * XrResult, else XR_SUCCESS. */
static XrResult follow_session(XrInstance instance, XrSession session, PFN_xrPollEvent poll, PFN_xrBeginSession begin,
                               PFN_xrEndSession end, int *running, int *done) {
    XrEventDataBuffer ev = {XR_TYPE_EVENT_DATA_BUFFER};
    while (poll(instance, &ev) == XR_SUCCESS) {
        if (ev.type == XR_TYPE_EVENT_DATA_SESSION_STATE_CHANGED) {
            XrSessionState state = ((XrEventDataSessionStateChanged *)&ev)->state;
            printf("state %d\n", (int)state);
            XrResult r = XR_SUCCESS;
            if (state == XR_SESSION_STATE_READY) {
                XrSessionBeginInfo info = {XR_TYPE_SESSION_BEGIN_INFO, NULL, XR_VIEW_CONFIGURATION_TYPE_PRIMARY_STEREO};
                r = begin(session, &info);
                *running = XR_SUCCEEDED(r);
            } else if (state == XR_SESSION_STATE_STOPPING) {
                r = end(session);
                *running = 0;
            } else if (state == XR_SESSION_STATE_EXITING || state == XR_SESSION_STATE_LOSS_PENDING) {
                *done = 1;
            }
            if (XR_FAILED(r)) return r;
        }
        ev = (XrEventDataBuffer){XR_TYPE_EVENT_DATA_BUFFER};
    }
    return XR_SUCCESS;
}

#endif
