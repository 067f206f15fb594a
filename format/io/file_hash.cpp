#include "format/io/file_hash.h"

#include <xxhash.h>

#include <cstdio>
#include <fstream>
#include <vector>

#include "format/io/file.h"

namespace ltb::io {

struct StreamHash::State {
  XXH3_state_t* st = XXH3_createState();
  State() { XXH3_64bits_reset(st); }
  ~State() { XXH3_freeState(st); }
};

StreamHash::StreamHash() : state_(std::make_unique<State>()) {}
StreamHash::~StreamHash() = default;

void StreamHash::AddBytes(const void* data, size_t size) { XXH3_64bits_update(state_->st, data, size); }

Status StreamHash::AddFile(const std::string& path) {
  LTB_RETURN_IF_ERROR(RequireRegularFile(path));
  std::ifstream f(path, std::ios::binary);
  if (!f) return NotFound(path + ": cannot open");
  std::vector<char> buf(1 << 16);
  while (f) {
    f.read(buf.data(), static_cast<std::streamsize>(buf.size()));
    AddBytes(buf.data(), static_cast<size_t>(f.gcount()));
  }
  return Status::Ok();
}

uint64_t StreamHash::Digest() const { return XXH3_64bits_digest(state_->st); }

std::string StreamHash::Hex() const {
  char b[17];
  std::snprintf(b, sizeof b, "%016llx", static_cast<unsigned long long>(Digest()));
  return b;
}

Result<std::string> HashFileHex(const std::string& path) {
  StreamHash h;
  LTB_RETURN_IF_ERROR(h.AddFile(path));
  return h.Hex();
}

}  // namespace ltb::io
