// Colour channel sets (docs/COLOUR.md): `sample --channels rgb -o X.ltm` writes one
// monochrome container per channel, X.r.ltm, X.g.ltm and X.b.ltm, each with a "channel"
// metadata key; every later stage runs on each file, and a command given X.ltm where no
// X.ltm exists but the channel files do takes the set.
#pragma once

#include <string>
#include <vector>

#include "format/status.h"

namespace ltb::stages {

inline constexpr int kChannels = 3;

// "r", "g", "b" for channel 0, 1, 2.
const char* ChannelName(int channel);
// X.ltm -> X.r.ltm (channel 0): the file of one channel of the set named X.ltm.
std::string ChannelPath(const std::string& set_path, int channel);

// The channel files of the set `path` names, in channel order: empty when `path` exists
// (one container) or when no file of the set does (the caller's open then reports the
// missing file). A set with a file missing, or a file whose "channel" metadata is not its
// name's channel (or is absent), is an error naming both files.
Result<std::vector<std::string>> ChannelFiles(const std::string& path);

}  // namespace ltb::stages
