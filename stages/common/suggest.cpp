#include "stages/common/suggest.h"

#include <algorithm>

namespace ltb {

size_t EditDistance(std::string_view a, std::string_view b) {
  std::vector<size_t> row(b.size() + 1);  // row[j]: distance of a[0, i) to b[0, j)
  for (size_t j = 0; j <= b.size(); ++j) row[j] = j;
  for (size_t i = 1; i <= a.size(); ++i) {
    size_t diag = row[0];
    row[0] = i;
    for (size_t j = 1; j <= b.size(); ++j) {
      const size_t up = row[j];
      row[j] = std::min({row[j] + 1, row[j - 1] + 1, diag + (a[i - 1] == b[j - 1] ? 0 : 1)});
      diag = up;
    }
  }
  return row[b.size()];
}

std::string Nearest(std::string_view name, const std::vector<std::string>& candidates, size_t max_edits) {
  std::string best;
  size_t best_d = max_edits + 1;
  for (const std::string& c : candidates) {
    if (const size_t d = EditDistance(name, c); d < best_d) best_d = d, best = c;
  }
  return best;
}

}  // namespace ltb
