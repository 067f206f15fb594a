// Base64 (RFC 4648, with padding) for small binary tables kept in JSON metadata (a factored
// bake's view factors, docs/GLOSSY.md).
#pragma once

#include <cstdint>
#include <string>
#include <vector>

#include "format/status.h"

namespace ltb::stages {

std::string Base64Encode(const void* data, size_t bytes);
// Fails on a character outside the alphabet, a bad length or misplaced padding.
Result<std::vector<uint8_t>> Base64Decode(const std::string& text);

// float32 little-endian arrays (the only host order ltbake builds for).
std::string FloatsToBase64(const std::vector<float>& v);
Result<std::vector<float>> FloatsFromBase64(const std::string& text);

}  // namespace ltb::stages
