// Sets of containers (docs/COLOUR.md, docs/GLOSSY.md): `sample --channels rgb -o X.ltm`
// writes one monochrome container per colour channel, X.r.ltm, X.g.ltm and X.b.ltm, and
// `sample --factor K` one per term, X.k0.ltm ..; each file has a "channel" metadata key
// naming its member. Every later stage runs on each file, and a command given X.ltm where
// no X.ltm exists but the member files do takes the set.
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
// X.ltm -> X.NAME.ltm: the member NAME of the set named X.ltm (channels r, g, b; a factored
// bake's terms k0, k1, ...).
std::string SetMemberPath(const std::string& set_path, const std::string& name);

// One file of a set: its member name ("r", "k2") and path.
struct SetMember {
  std::string name, path;
};

// A set member's first file: `path` itself when it exists, else its red channel's file when
// that exists (a colour factored bake's term X.k0.ltm is the colour set X.k0.r.ltm ...), else
// `path`.
std::string SetLeaf(const std::string& path);

// The files of the set `path` names, in order: X.r.ltm, X.g.ltm, X.b.ltm (a colour set) or
// X.k0.ltm .. (a factored bake, its terms listed in each file's "channel" metadata; in
// colour each term X.k0.ltm is itself a colour set X.k0.r.ltm .., the terms listed under
// "term", and the member's path is the term's set name X.k0.ltm). Empty
// when `path` exists (one container) or when no file of a set does (the caller's open then
// reports the missing file). A set with a file missing, or a file whose "channel" metadata
// is not its name's (or is absent), is an error naming both files.
Result<std::vector<SetMember>> ChannelFiles(const std::string& path);

}  // namespace ltb::stages
