// Test helper: the encoding-5 (sparse-coded) payload of a raw little-endian i32 chunk, so
// tests/format/coded_oracle.py can decode it from docs/FORMAT.md alone.
// usage: ltb_coded_helper LINE_LENGTH WIDTH IN OUT
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <iterator>
#include <vector>

#include "format/coded_codec.h"

int main(int argc, char** argv) {
  if (argc != 5) {
    std::fprintf(stderr, "usage: %s LINE_LENGTH WIDTH IN OUT\n", argv[0]);
    return 2;
  }
  std::ifstream in(argv[3], std::ios::binary);
  std::vector<char> raw((std::istreambuf_iterator<char>(in)), {});
  std::vector<std::byte> payload =
      ltb::format::EncodeCodedPayload(ltb::format::ByteSpan(reinterpret_cast<const std::byte*>(raw.data()), raw.size()),
                                      std::strtoull(argv[1], nullptr, 10), std::strtoull(argv[2], nullptr, 10));
  if (payload.empty()) {
    std::fprintf(stderr, "cannot code %zu bytes as lines of %s, %s wide\n", raw.size(), argv[1], argv[2]);
    return 1;
  }
  std::ofstream(argv[4], std::ios::binary).write(reinterpret_cast<const char*>(payload.data()), payload.size());
  return 0;
}
