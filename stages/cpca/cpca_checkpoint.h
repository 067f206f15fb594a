// The checkpoint `ltbake cpca` keeps beside its output (OUT.cpca-state) so an interrupted
// run resumes at the last pass boundary. Layout (little-endian): magic "LTBCPCA1" (8
// bytes), u64 header length, header (JSON: what run it belongs to and the counters), u64
// value count, that many f64 values (the model), u64 XXH3-64 of every byte before it.
// Written to OUT.cpca-state.tmp, synced and renamed over the old one: a kill at any instant
// leaves the previous or the new checkpoint, never a torn one.
#pragma once

#include <nlohmann/json.hpp>
#include <optional>
#include <string>
#include <vector>

#include "format/status.h"

namespace ltb::stages {

struct CpcaCheckpoint {
  nlohmann::json header;
  std::vector<double> values;
};

Status WriteCpcaCheckpoint(const std::string& path, const CpcaCheckpoint& checkpoint);
// nullopt when there is no file; kDataLoss (naming the file and what is wrong) when it is
// damaged or holds more than max_values values.
Result<std::optional<CpcaCheckpoint>> ReadCpcaCheckpoint(const std::string& path, uint64_t max_values);

}  // namespace ltb::stages
