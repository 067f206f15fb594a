// XXH3-64 over a stream of files and bytes: the scene hash (the scene file and its meshes),
// run.json's hashes of the maps and images a bake reads.
#pragma once

#include <cstddef>
#include <cstdint>
#include <memory>
#include <string>

#include "format/status.h"

namespace ltb::io {

class StreamHash {
 public:
  StreamHash();
  ~StreamHash();
  StreamHash(const StreamHash&) = delete;
  StreamHash& operator=(const StreamHash&) = delete;

  void AddBytes(const void* data, size_t size);
  // Appends the bytes of the regular file at `path` (a FIFO or a device is refused before it
  // is opened: it could block or never end); an error names the path.
  Status AddFile(const std::string& path);
  uint64_t Digest() const;
  std::string Hex() const;  // the digest as 16 lowercase hex digits

 private:
  struct State;
  std::unique_ptr<State> state_;
};

// The XXH3-64 of a regular file's bytes as 16 lowercase hex digits.
Result<std::string> HashFileHex(const std::string& path);

}  // namespace ltb::io
