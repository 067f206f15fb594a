// Format and tool versions. The byte-level spec is docs/FORMAT.md; change both together.
#pragma once

#include <cstdint>

namespace ltb {

inline constexpr const char* kToolVersion = "0.1.0";

namespace format {

// Current format version written by this build.
inline constexpr uint16_t kFormatMajor = 1;
inline constexpr uint16_t kFormatMinor = 2;
// Version history (named so code can say when a feature arrived):
inline constexpr uint16_t kMinorInitial = 0;  // 1.0: header, JSON metadata, chunk frames, index, trailer
inline constexpr uint16_t kMinorSparse = 1;   // 1.1: sparse chunk encodings (kSparse, kSparseZstd)
inline constexpr uint16_t kMinorCoded = 2;    // 1.2: the coded sparse encoding (kCoded, i32 chunks)

// Required-feature bits (header): a reader must refuse a file with a bit it does not know.
// None are defined; chunk encodings are not features: a reader refuses an unknown encoding
// per chunk (so a 1.0 reader opens a 1.1 file and refuses only its sparse chunks, and a 1.1 reader
// opens a 1.2 file and refuses only its coded chunks).
inline constexpr uint64_t kKnownRequiredFeatures = 0;

}  // namespace format
}  // namespace ltb
