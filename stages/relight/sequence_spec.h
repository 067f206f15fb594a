// The --sequence grammar (docs/SEQUENCE.md), parsed without opening any map: shared by
// `relight --sequence` (run_sequence.h) and recipes' [relight] sequence key, which checks it
// when the recipe is read.
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "format/status.h"

namespace ltb::stages {

// One segment of --sequence: rotate:DEG_PER_FRAME:FRAMES, hold:FRAMES, maps:A+B+...,
// fade:A+B:FRAMES.
struct SequenceSegment {
  enum class Kind { kRotate, kHold, kMaps, kFade } kind = Kind::kHold;
  double degrees = 0;  // per frame (rotate)
  uint64_t frames = 0;
  std::vector<std::string> maps;  // maps: one per frame; fade: the two ends
};
// Checked: at least one frame, at most 1,000,000 in all; every count and angle finite.
Result<std::vector<SequenceSegment>> ParseSequence(const std::string& spec);

}  // namespace ltb::stages
