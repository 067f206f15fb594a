// Small integer helpers shared by the format and every stage.
#pragma once

#include <cstdint>

namespace ltb {

constexpr bool IsPowerOfTwo(uint64_t v) { return v != 0 && (v & (v - 1)) == 0; }

}  // namespace ltb
