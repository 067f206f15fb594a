// "Did you mean": the known name nearest to a mistyped one, for usage errors (an unknown
// command, an unknown recipe or scene key).
#pragma once

#include <cstddef>
#include <string>
#include <string_view>
#include <vector>

namespace ltb {

// Levenshtein distance: the fewest single-character insertions, deletions and
// substitutions that turn a into b.
size_t EditDistance(std::string_view a, std::string_view b);

// The candidate nearest to name when it is at most max_edits away (the first such on a tie),
// else "".
std::string Nearest(std::string_view name, const std::vector<std::string>& candidates, size_t max_edits = 2);

}  // namespace ltb
