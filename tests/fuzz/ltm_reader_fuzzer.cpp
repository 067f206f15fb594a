// libFuzzer target: any byte string as an .ltm file. Opens it, reads every committed
// chunk (dense and sparse), summarizes every array and runs verify; none of it may crash,
// hang or leak.
// Build and run: docs/FUZZING.md.
#include <sys/mman.h>
#include <unistd.h>

#include <cstddef>
#include <cstdint>
#include <string>

#include "format/io/array_summary.h"
#include "format/io/container_reader.h"
#include "format/io/verifier.h"

extern "C" int LLVMFuzzerTestOneInput(const uint8_t* data, size_t size) {
  int fd = memfd_create("ltm-fuzz", MFD_CLOEXEC);
  if (fd < 0) return 0;
  size_t done = 0;
  while (done < size) {
    ssize_t n = write(fd, data + done, size - done);
    if (n <= 0) break;
    done += static_cast<size_t>(n);
  }
  std::string path = "/proc/self/fd/" + std::to_string(fd);
  auto reader = ltb::io::ContainerReader::Open(path);
  if (reader.ok()) {
    for (const auto& e : reader->chunk_frames()) {
      (void)reader->ReadChunk(e.header.array, e.header.chunk_index);
      (void)reader->ReadSparse(e.header.array, e.header.chunk_index);
    }
    for (uint32_t a = 0; a < reader->metadata().arrays.size(); ++a) (void)ltb::io::SummarizeArray(*reader, a, 1);
  }
  (void)ltb::io::VerifyContainer(path);
  close(fd);
  return 0;
}
