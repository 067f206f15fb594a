#include "stages/relight/sequence_spec.h"

#include <cmath>
#include <cstdlib>

#include "stages/common/quantity.h"

namespace ltb::stages {
namespace {

constexpr uint64_t kMaxFrames = 1000000;

std::vector<std::string> Split(const std::string& s, char sep) {
  std::vector<std::string> out;
  size_t pos = 0;
  while (true) {
    size_t end = s.find(sep, pos);
    out.push_back(s.substr(pos, end == std::string::npos ? std::string::npos : end - pos));
    if (end == std::string::npos) return out;
    pos = end + 1;
  }
}

bool ParseCount(const std::string& s, uint64_t* out) {
  if (s.empty() || s.size() > 7 || s.find_first_not_of("0123456789") != std::string::npos) return false;
  *out = std::stoull(s);
  return *out >= 1 && *out <= kMaxFrames;
}

}  // namespace

Result<std::vector<SequenceSegment>> ParseSequence(const std::string& spec) {
  std::vector<SequenceSegment> out;
  uint64_t total = 0;
  auto bad = [&](const std::string& seg, const std::string& why) {
    return InvalidArgument("--sequence: segment \"" + seg + "\": " + why +
                           " (segments: rotate:DEG_PER_FRAME:FRAMES, hold:FRAMES, maps:A.exr+B.hdr+..., "
                           "fade:A.exr+B.exr:FRAMES, comma-separated)");
  };
  if (spec.empty()) return InvalidArgument("--sequence is empty; e.g. rotate:3.6:100,hold:25");
  for (const std::string& seg : Split(spec, ',')) {
    SequenceSegment s;
    const size_t colon = seg.find(':');
    const std::string kind = seg.substr(0, colon);
    const std::string rest = colon == std::string::npos ? "" : seg.substr(colon + 1);
    if (kind == "rotate") {
      s.kind = SequenceSegment::Kind::kRotate;
      const size_t c = rest.find(':');
      if (c == std::string::npos) return bad(seg, "expected rotate:DEG_PER_FRAME:FRAMES");
      const std::string deg = rest.substr(0, c);
      auto degrees = ParseDecimal(deg, -360, 360);
      if (!degrees.ok()) return bad(seg, "the degrees per frame: " + degrees.status().message());
      s.degrees = *degrees;
      if (!ParseCount(rest.substr(c + 1), &s.frames)) {
        return bad(seg, "the frame count \"" + rest.substr(c + 1) + "\" is not an integer in [1, 1000000]");
      }
    } else if (kind == "hold") {
      s.kind = SequenceSegment::Kind::kHold;
      if (!ParseCount(rest, &s.frames))
        return bad(seg, "the frame count \"" + rest + "\" is not an integer in [1, 1000000]");
    } else if (kind == "maps") {
      s.kind = SequenceSegment::Kind::kMaps;
      s.maps = Split(rest, '+');
      for (const auto& m : s.maps)
        if (m.empty()) return bad(seg, "a map path is empty");
      s.frames = s.maps.size();
    } else if (kind == "fade") {
      s.kind = SequenceSegment::Kind::kFade;
      const size_t c = rest.rfind(':');
      if (c == std::string::npos) return bad(seg, "expected fade:A+B:FRAMES");
      s.maps = Split(rest.substr(0, c), '+');
      if (s.maps.size() != 2 || s.maps[0].empty() || s.maps[1].empty()) {
        return bad(seg, "a fade takes two maps joined by +");
      }
      if (!ParseCount(rest.substr(c + 1), &s.frames)) {
        return bad(seg, "the frame count \"" + rest.substr(c + 1) + "\" is not an integer in [1, 1000000]");
      }
    } else {
      return bad(seg, "unknown kind \"" + kind + "\"");
    }
    total += s.frames;
    if (total > kMaxFrames) return bad(seg, "the sequence has more than 1000000 frames");
    out.push_back(std::move(s));
  }
  return out;
}

}  // namespace ltb::stages
