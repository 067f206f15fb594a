// Helpers for format tests: temporary directories and small deterministic matrices.
#pragma once

#include <gtest/gtest.h>

#include <cstdint>
#include <filesystem>
#include <fstream>
#include <iterator>
#include <nlohmann/json.hpp>
#include <random>
#include <string>
#include <vector>

#include "format/array_spec.h"
#include "format/io/array_summary.h"
#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "format/io/verifier.h"

namespace ltb::test {

class TempDir {
 public:
  TempDir() {
    std::string tmpl = (std::filesystem::temp_directory_path() / "ltb-test-XXXXXX").string();
    path_ = mkdtemp(tmpl.data());
  }
  ~TempDir() { std::filesystem::remove_all(path_); }
  std::string File(const std::string& name) const { return (std::filesystem::path(path_) / name).string(); }

 private:
  std::string path_;
};

inline std::vector<char> ReadFileBytes(const std::string& path) {
  std::ifstream f(path, std::ios::binary);
  return std::vector<char>(std::istreambuf_iterator<char>(f), {});
}

// rows x cols values in row-major order; row r is all zero when r % 7 == 3 so that
// some chunks are all-zero, and some rows repeat a pattern so zstd has work to do.
inline std::vector<float> MakeMatrix(uint64_t rows, uint64_t cols, uint32_t seed) {
  std::mt19937 rng(seed);
  std::uniform_real_distribution<float> u(-1.0f, 1.0f);
  std::vector<float> m(rows * cols);
  for (uint64_t r = 0; r < rows; ++r)
    for (uint64_t c = 0; c < cols; ++c)
      m[r * cols + c] = (r % 7 == 3) ? 0.0f : (r % 5 == 1 ? static_cast<float>(c % 4) : u(rng));
  return m;
}

// The values of chunk `chunk` of `spec` (row- or column-major as the layout says) from
// the row-major matrix `m`.
template <typename T>
std::vector<T> ChunkValues(const format::ArraySpec& spec, const std::vector<T>& m, uint64_t chunk) {
  format::ChunkExtent e = spec.Extent(chunk);
  std::vector<T> v(e.Elements());
  for (uint64_t r = 0; r < e.rows; ++r)
    for (uint64_t c = 0; c < e.cols; ++c) {
      T x = m[(e.row0 + r) * spec.cols + e.col0 + c];
      if (spec.layout == format::Layout::kRows)
        v[r * e.cols + c] = x;
      else
        v[c * e.rows + r] = x;
    }
  return v;
}

inline nlohmann::json MatrixMetadata(uint64_t rows, uint64_t cols, format::Layout layout, uint64_t block) {
  format::ArraySpec s;
  s.name = "matrix";
  s.rows = rows;
  s.cols = cols;
  s.layout = layout;
  s.block = block;
  return {{"arrays", {s.ToJson()}}, {"note", "test"}};
}

template <typename T>
format::ByteSpan AsBytes(const std::vector<T>& v) {
  return {reinterpret_cast<const std::byte*>(v.data()), v.size() * sizeof(T)};
}

// Writes a complete container whose matrix (array 0, described by `metadata`) holds `m`
// (row-major), every chunk encoded with `eo`.
template <typename T>
Status WriteValues(const std::string& path, const nlohmann::json& metadata, const std::vector<T>& m,
                   const format::EncodeOptions& eo) {
  auto w = io::ContainerWriter::Open(path, metadata);
  if (!w.ok()) return w.status();
  for (uint64_t i = 0; i < w->metadata().matrix().ChunkCount(); ++i) {
    auto v = ChunkValues(w->metadata().matrix(), m, i);
    Status s = w->Put(0, i, AsBytes(v), eo);
    if (!s.ok()) return s;
  }
  return w->Finish();
}

// Writes a complete container of MakeMatrix(rows, cols, seed).
inline void WriteMatrix(const std::string& path, uint64_t rows, uint64_t cols, format::Layout layout, uint64_t block,
                        uint32_t seed, bool zstd) {
  format::EncodeOptions eo;
  eo.zstd = zstd;
  Status s = WriteValues(path, MatrixMetadata(rows, cols, layout, block), MakeMatrix(rows, cols, seed), eo);
  if (!s.ok()) throw std::runtime_error(s.message());
}

// The content_hash of array 0 of a container ("" after a failed expectation).
inline std::string HashOf(const std::string& path) {
  auto r = io::ContainerReader::Open(path);
  EXPECT_TRUE(r.ok()) << r.status().message();
  if (!r.ok()) return "";
  auto s = io::SummarizeArray(*r, 0, 2);
  EXPECT_TRUE(s.ok()) << s.status().message();
  return s.ok() ? s->content_hash : "";
}

// A file left by a writer stopped after `stop` mutations: it verifies without a problem,
// opens, and lists exactly the chunks that verify.
inline void ExpectInterruptedFileIntact(const std::string& path, uint64_t stop) {
  io::VerifyReport v = io::VerifyContainer(path);
  EXPECT_TRUE(v.readable) << "stopped after " << stop;
  EXPECT_TRUE(v.problems.empty()) << "stopped after " << stop << ": " << v.problems.front();
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok()) << "stopped after " << stop << ": " << r.status().message();
  EXPECT_TRUE(r->problems().empty()) << "stopped after " << stop;
  EXPECT_EQ(r->chunk_frames().size(), v.chunks_ok) << "stopped after " << stop;
}

}  // namespace ltb::test
