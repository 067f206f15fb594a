#include <xxhash.h>

#include "format/bytes.h"

namespace ltb::format {

uint64_t Checksum(ByteSpan bytes) { return XXH3_64bits(bytes.data(), bytes.size()); }

}  // namespace ltb::format
