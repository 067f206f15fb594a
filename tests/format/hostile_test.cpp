// Hand-built headers and frames (laid out field by field from docs/FORMAT.md, hashed with
// xxHash directly, not with the code under test): version refusal, feature flags,
// hostile sizes and offsets, unknown optional and required sections.
#include <gtest/gtest.h>
#include <xxhash.h>

#include <cstring>
#include <fstream>
#include <optional>

#include "format/io/array_summary.h"
#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "format/io/verifier.h"
#include "test_util.h"

namespace ltb {
namespace {

using Bytes = std::vector<unsigned char>;

void Put16(Bytes& b, size_t at, uint16_t v) { std::memcpy(&b[at], &v, 2); }
void Put32(Bytes& b, size_t at, uint32_t v) { std::memcpy(&b[at], &v, 4); }
void Put64(Bytes& b, size_t at, uint64_t v) { std::memcpy(&b[at], &v, 8); }
void Seal56(Bytes& b, size_t at) { Put64(b, at + 56, XXH3_64bits(&b[at], 56)); }

const std::string kMeta =
    R"({"arrays":[{"block":2,"dtype":"f32","layout":"rows","name":"matrix","shape":[4,2]}]})";

// A file header (64 bytes) followed by the metadata, padded to 64 bytes.
Bytes Header(uint16_t major, uint16_t minor, uint64_t required = 0, std::string meta = kMeta,
             int64_t meta_len_override = -1) {
  Bytes b(64 + (meta.size() + 63) / 64 * 64, 0);
  const unsigned char magic[8] = {0x89, 'L', 'T', 'M', '\r', '\n', 0x1a, '\n'};
  std::memcpy(&b[0], magic, 8);                       // magic
  Put16(b, 8, major);                                 // format major
  Put16(b, 10, minor);                                // format minor
  Put32(b, 12, 64);                                   // header size
  Put64(b, 16, required);                             // required-feature flags
  Put64(b, 24, 0);                                    // optional-feature flags
  Put64(b, 32, meta_len_override >= 0 ? uint64_t(meta_len_override) : meta.size());  // metadata length
  Put64(b, 40, XXH3_64bits(meta.data(), meta.size()));  // metadata checksum
  Put64(b, 48, 0);                                    // reserved
  Seal56(b, 0);                                       // header checksum
  std::memcpy(&b[64], meta.data(), meta.size());
  return b;
}

// A frame header for `payload` with the given fields, then the payload padded to 64.
void AppendFrame(Bytes& b, uint16_t type, uint16_t flags, uint32_t array, uint16_t encoding, uint64_t chunk,
                 const Bytes& payload, uint64_t decoded_length,
                 std::optional<uint64_t> payload_len_override = std::nullopt) {
  size_t at = b.size();
  b.resize(at + 64 + (payload.size() + 63) / 64 * 64, 0);
  Put32(b, at + 0, 0x464D544C);                       // "LTMF"
  Put16(b, at + 4, type);                             // frame type
  Put16(b, at + 6, flags);                            // flags (1 = optional)
  Put64(b, at + 8, payload_len_override.value_or(payload.size()));  // payload length
  Put32(b, at + 16, array);                           // array id
  Put16(b, at + 20, encoding);                        // encoding
  Put64(b, at + 24, chunk);                           // chunk index
  Put64(b, at + 32, decoded_length);                  // decoded length
  Put64(b, at + 40, XXH3_64bits(payload.data(), payload.size()));  // payload checksum
  Seal56(b, at);
  if (!payload.empty()) std::memcpy(&b[at + 64], payload.data(), payload.size());
}

Bytes RawChunk(float base) {
  Bytes p(16);
  float v[4] = {base, base + 1, base + 2, base + 3};
  std::memcpy(p.data(), v, 16);
  return p;
}

std::string WriteFile(const test::TempDir& dir, const Bytes& b, const std::string& name = "h.ltm") {
  std::string path = dir.File(name);
  std::ofstream(path, std::ios::binary).write(reinterpret_cast<const char*>(b.data()), b.size());
  return path;
}

Status OpenStatus(const std::string& path) {
  auto r = io::ContainerReader::Open(path);
  return r.ok() ? Status::Ok() : r.status();
}

TEST(Hostile, HandBuiltFileReads) {
  test::TempDir dir;
  Bytes b = Header(1, 0);
  AppendFrame(b, 1, 0, 0, 0, 0, RawChunk(1), 16);
  AppendFrame(b, 1, 0, 0, 1, 1, {}, 16);  // all-zero chunk, no payload
  auto path = WriteFile(dir, b);
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_TRUE(r->complete());
  auto c = r->ReadChunk(0, 0);
  ASSERT_TRUE(c.ok());
  EXPECT_EQ(c->as<float>()[3], 4.0f);
}

TEST(Version, RefusesNewerMajorNamingBothVersions) {
  test::TempDir dir;
  auto path = WriteFile(dir, Header(2, 3));
  Status s = OpenStatus(path);
  EXPECT_EQ(s.code(), StatusCode::kUnimplemented);
  EXPECT_NE(s.message().find("format 2.3"), std::string::npos) << s.message();
  EXPECT_NE(s.message().find("reads up to 1.0"), std::string::npos) << s.message();
  EXPECT_NE(s.message().find("upgrade ltbake"), std::string::npos) << s.message();
}

TEST(Version, ReadsNewerMinor) {
  test::TempDir dir;
  Bytes b = Header(1, 9);
  AppendFrame(b, 1, 0, 0, 1, 0, {}, 16);
  AppendFrame(b, 1, 0, 0, 1, 1, {}, 16);
  auto r = io::ContainerReader::Open(WriteFile(dir, b));
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_TRUE(r->complete());
}

TEST(Version, RefusesUnknownRequiredFeature) {
  test::TempDir dir;
  Status s = OpenStatus(WriteFile(dir, Header(1, 0, /*required=*/1u << 5)));
  EXPECT_EQ(s.code(), StatusCode::kUnimplemented);
  EXPECT_NE(s.message().find("0x0000000000000020"), std::string::npos) << s.message();
}

TEST(Sections, SkipsUnknownOptionalFrameAndKeepsUnknownMetadataKeys) {
  test::TempDir dir;
  std::string meta = R"({"arrays":[{"block":2,"dtype":"f32","layout":"rows","name":"matrix","shape":[4,2]}],)"
                     R"("future_key":{"x":1}})";
  Bytes b = Header(1, 0, 0, meta);
  AppendFrame(b, 1, 0, 0, 0, 0, RawChunk(1), 16);
  AppendFrame(b, 77, 1, 0, 0, 0, Bytes(100, 0xAB), 100);  // unknown type 77, optional
  AppendFrame(b, 1, 0, 0, 0, 1, RawChunk(5), 16);
  auto path = WriteFile(dir, b);
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_TRUE(r->complete());
  EXPECT_TRUE(r->problems().empty());
  EXPECT_EQ(r->metadata().json["future_key"]["x"], 1);
  auto v = io::VerifyContainer(path);
  EXPECT_TRUE(v.problems.empty());
  ASSERT_EQ(v.notes.size(), 1u);
  EXPECT_NE(v.notes[0].find("optional frame of unknown type 77"), std::string::npos);
  // A writer resumes past it and seals the file.
  auto w = io::ContainerWriter::Open(path, nlohmann::json::parse(meta));
  ASSERT_TRUE(w.ok()) << w.status().message();
  EXPECT_EQ(w->resume_info().committed_chunks, 2u);
  ASSERT_TRUE(w->Finish().ok());
  EXPECT_TRUE(io::VerifyContainer(path).complete);
}

TEST(Sections, RefusesUnknownRequiredFrame) {
  test::TempDir dir;
  Bytes b = Header(1, 0);
  AppendFrame(b, 77, 0, 0, 0, 0, Bytes(8, 1), 8);  // unknown type, not optional
  Status s = OpenStatus(WriteFile(dir, b));
  EXPECT_EQ(s.code(), StatusCode::kUnimplemented);
  EXPECT_NE(s.message().find("type 77"), std::string::npos) << s.message();
}

TEST(Hostile, MetadataLengthBeyondFile) {
  test::TempDir dir;
  Status s = OpenStatus(WriteFile(dir, Header(1, 0, 0, kMeta, 5000)));
  EXPECT_EQ(s.code(), StatusCode::kDataLoss);
  EXPECT_NE(s.message().find("metadata length 5000 runs past the end"), std::string::npos) << s.message();
}

TEST(Hostile, MetadataLengthHuge) {
  test::TempDir dir;
  Status s = OpenStatus(WriteFile(dir, Header(1, 0, 0, kMeta, int64_t(1) << 60)));
  EXPECT_EQ(s.code(), StatusCode::kDataLoss);
  EXPECT_NE(s.message().find("exceeds the cap"), std::string::npos) << s.message();
}

TEST(Hostile, HugeChunkCountIsNotAllocated) {
  test::TempDir dir;
  // 2^40 rows in blocks of 1: 2^40 chunks; nothing may be sized by that count.
  std::string meta = R"({"arrays":[{"block":1,"dtype":"f32","layout":"rows","name":"matrix","shape":[1099511627776,1]}]})";
  Bytes b = Header(1, 0, 0, meta);
  AppendFrame(b, 1, 0, 0, 0, 123456789, Bytes(4, 1), 4);
  auto path = WriteFile(dir, b);
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_EQ(r->committed(0), 1u);
  EXPECT_FALSE(r->complete());
  auto v = io::VerifyContainer(path);
  EXPECT_EQ(v.chunks_expected, uint64_t(1) << 40);
  EXPECT_TRUE(v.problems.empty());
  // inspect's content pass visits the committed chunks only.
  auto sum = io::SummarizeArray(*r, 0, 2);
  ASSERT_TRUE(sum.ok()) << sum.status().message();
  EXPECT_EQ(sum->chunks_read, 1u);
  EXPECT_EQ(sum->chunks_missing, (uint64_t(1) << 40) - 1);
  EXPECT_TRUE(sum->content_hash.empty());
}

TEST(Hostile, ShapeBeyondCaps) {
  test::TempDir dir;
  std::string meta = R"({"arrays":[{"block":1,"dtype":"f32","layout":"rows","name":"matrix","shape":[4,99999999999999]}]})";
  Status s = OpenStatus(WriteFile(dir, Header(1, 0, 0, meta)));
  EXPECT_EQ(s.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s.message().find("shape 4x99999999999999"), std::string::npos) << s.message();
}

TEST(Hostile, FramePayloadPastEndOfFile) {
  test::TempDir dir;
  Bytes b = Header(1, 0);
  AppendFrame(b, 1, 0, 0, 0, 0, RawChunk(1), 16, /*payload_len_override=*/uint64_t(1) << 30);
  auto path = WriteFile(dir, b);
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->committed(0), 0u);  // not committed: it does not fit
  auto v = io::VerifyContainer(path);
  EXPECT_FALSE(v.complete);
  EXPECT_GT(v.uncommitted_tail_bytes, 0u);
}

TEST(Hostile, PayloadLengthOverflow) {
  test::TempDir dir;
  Bytes b = Header(1, 0);
  AppendFrame(b, 1, 0, 0, 0, 0, RawChunk(1), 16, /*payload_len_override=*/~uint64_t(1));  // 2^64 - 2
  auto r = io::ContainerReader::Open(WriteFile(dir, b));
  ASSERT_TRUE(r.ok());
  EXPECT_EQ(r->committed(0), 0u);
}

TEST(Hostile, DecodedLengthDisagreesWithMetadata) {
  test::TempDir dir;
  Bytes b = Header(1, 0);
  AppendFrame(b, 1, 0, 0, 1, 0, {}, uint64_t(1) << 40);  // a zero chunk claiming 1 TiB
  AppendFrame(b, 1, 0, 0, 1, 1, {}, 16);
  auto path = WriteFile(dir, b);
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok());
  ASSERT_EQ(r->problems().size(), 1u);
  EXPECT_NE(r->problems()[0].find("decoded length 1099511627776 differs from the 16 bytes"), std::string::npos)
      << r->problems()[0];
  EXPECT_EQ(r->ReadChunk(0, 0).status().code(), StatusCode::kNotFound);
  auto v = io::VerifyContainer(path);
  EXPECT_FALSE(v.problems.empty());
}

TEST(Hostile, IndexOffsetPastEnd) {
  test::TempDir dir;
  Bytes b = Header(1, 0);
  AppendFrame(b, 1, 0, 0, 1, 0, {}, 16);
  AppendFrame(b, 1, 0, 0, 1, 1, {}, 16);
  size_t at = b.size();
  b.resize(at + 64, 0);
  const char magic[8] = {'L', 'T', 'M', 'T', 'R', 'A', 'I', 'L'};
  std::memcpy(&b[at], magic, 8);        // trailer magic
  Put64(b, at + 8, uint64_t(1) << 50);  // index offset: far past the end
  Put64(b, at + 16, b.size());          // file length
  Seal56(b, at);
  auto path = WriteFile(dir, b);
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_FALSE(r->sealed());
  EXPECT_EQ(r->committed(0), 2u);  // found by scanning
  auto v = io::VerifyContainer(path);
  EXPECT_FALSE(v.complete);
}

TEST(Hostile, IndexCountLargerThanPayload) {
  test::TempDir dir;
  Bytes b = Header(1, 0);
  AppendFrame(b, 1, 0, 0, 1, 0, {}, 16);
  AppendFrame(b, 1, 0, 0, 1, 1, {}, 16);
  size_t index_at = b.size();
  Bytes idx(8, 0);
  uint64_t count = uint64_t(1) << 60;  // claims 2^60 entries in an 8-byte payload
  std::memcpy(idx.data(), &count, 8);
  AppendFrame(b, 2, 0, 0, 0, 0, idx, 8);
  size_t at = b.size();
  b.resize(at + 64, 0);
  const char magic[8] = {'L', 'T', 'M', 'T', 'R', 'A', 'I', 'L'};
  std::memcpy(&b[at], magic, 8);
  Put64(b, at + 8, index_at);
  Put64(b, at + 16, b.size());
  Seal56(b, at);
  auto path = WriteFile(dir, b);
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok()) << r.status().message();
  ASSERT_FALSE(r->problems().empty());
  EXPECT_NE(r->problems()[0].find("index claims 1152921504606846976 entries"), std::string::npos)
      << r->problems()[0];
  auto v = io::VerifyContainer(path);
  EXPECT_FALSE(v.problems.empty());
}

TEST(Hostile, DeeplyNestedMetadataDoesNotCrash) {
  test::TempDir dir;
  std::string meta(200000, '[');
  Status s = OpenStatus(WriteFile(dir, Header(1, 0, 0, meta)));
  EXPECT_FALSE(s.ok());
  std::string meta2 = std::string(100000, '[') + std::string(100000, ']');
  Status s2 = OpenStatus(WriteFile(dir, Header(1, 0, 0, meta2), "h2.ltm"));
  EXPECT_EQ(s2.code(), StatusCode::kInvalidArgument);
  EXPECT_NE(s2.message().find("not a JSON object"), std::string::npos) << s2.message();
}

TEST(Hostile, EmptyAndTinyFiles) {
  test::TempDir dir;
  for (size_t n : {0, 1, 8, 63}) {
    Bytes b = Header(1, 0);
    b.resize(n);
    std::string name = "t";
    name += std::to_string(n);
    Status s = OpenStatus(WriteFile(dir, b, name + ".ltm"));
    EXPECT_FALSE(s.ok());
    EXPECT_NE(s.message().find("shorter than the 64-byte .ltm header"), std::string::npos) << s.message();
  }
}

}  // namespace
}  // namespace ltb
