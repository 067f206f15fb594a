// `ltbake view`'s HTTP server (docs/VIEW.md), bound to 127.0.0.1 only:
//   GET /            the page (self-contained: no CDN, no build step)
//   GET /frame.png   one relit frame: ?map=K&rotate=DEG&terms=N|all&method=pbi|bi|nwa&exposure=E
//                    (its figures in the X-Ltb-Stats header, JSON)
//   GET /stats       the last frame's figures (JSON)
//   GET /env.png     the last frame's lighting as a lat-long strip, its terms tinted red
//   POST /map        a map from the page (?name=FILE.exr|.hdr, the file as the body, header
//                    X-Ltb-Upload): loaded like an --env map; answers {"map": K, "maps": [...]}
// Anything else is 404; bad parameters are 400 naming the parameter. Frames are rendered
// one at a time (the page keeps one request in flight, so nothing queues up).
#pragma once

#include <functional>
#include <string>

#include "format/status.h"
#include "stages/view/view_session.h"

namespace ltb::stages::view {

// Serves until `stop()` returns true (polled every 100 ms). `ready(url)` is called once,
// when the server listens.
Status Serve(const ViewOptions& options, const std::function<void(const std::string& url)>& ready,
             const std::function<bool()>& stop);

// The page's HTML; `defaults_json` ({"terms": N or "all", "method": "pbi", "reference": bool,
// "maps": [names], "sequence_frames": N, "max_upload_bytes": N, "max_maps": N}) sets its controls.
std::string PageHtml(const std::string& defaults_json);

}  // namespace ltb::stages::view
