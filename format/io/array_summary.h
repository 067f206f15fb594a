// One pass over an array's committed chunks: content_hash and value statistics.
#pragma once

#include <cstdint>
#include <limits>
#include <string>

#include "format/io/container_reader.h"
#include "format/progress.h"

namespace ltb::io {

struct ArrayStats {
  uint64_t count = 0;  // elements examined
  uint64_t nonzero = 0;
  uint64_t nan = 0;
  uint64_t inf = 0;
  double min = std::numeric_limits<double>::infinity();  // over finite values
  double max = -std::numeric_limits<double>::infinity();
  double sum = 0;  // over finite values, in chunk order
};

struct ArraySummary {
  std::string content_hash;  // empty when the array is incomplete (a shard: its slice)
  uint64_t hash_sum = 0;     // the content_hash sum (ContentHasher::sum) of the chunks read
  uint64_t chunks_read = 0;
  uint64_t chunks_missing = 0;
  ArrayStats stats;
};

// Reads every committed chunk of `array` (checksums verified) with `threads` workers.
// The result does not depend on the thread count.
Result<ArraySummary> SummarizeArray(const ContainerReader& reader, uint32_t array, int threads,
                                    const Progress& progress = {});

}  // namespace ltb::io
