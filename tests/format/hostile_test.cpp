// Hand-built headers and frames (laid out field by field from docs/FORMAT.md, hashed with
// xxHash directly, not with the code under test): version refusal, feature flags,
// hostile sizes and offsets, unknown optional and required sections, malformed sparse and
// coded payloads.
#include <gtest/gtest.h>
#include <xxhash.h>

#include <cstring>
#include <fstream>
#include <optional>

#include "format/chunk_codec.h"
#include "format/io/array_summary.h"
#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "format/io/verifier.h"
#include "format/json_text.h"
#include "test_util.h"

namespace ltb {
namespace {

using Bytes = std::vector<unsigned char>;

void Put16(Bytes& b, size_t at, uint16_t v) { std::memcpy(&b[at], &v, 2); }
void Put32(Bytes& b, size_t at, uint32_t v) { std::memcpy(&b[at], &v, 4); }
void Put64(Bytes& b, size_t at, uint64_t v) { std::memcpy(&b[at], &v, 8); }
void Seal56(Bytes& b, size_t at) { Put64(b, at + 56, XXH3_64bits(&b[at], 56)); }

const std::string kMeta = R"({"arrays":[{"block":2,"dtype":"f32","layout":"rows","name":"matrix","shape":[4,2]}]})";

// A file header (64 bytes) followed by the metadata, padded to 64 bytes.
Bytes Header(uint16_t major, uint16_t minor, uint64_t required = 0, std::string meta = kMeta,
             int64_t meta_len_override = -1) {
  Bytes b(64 + (meta.size() + 63) / 64 * 64, 0);
  const unsigned char magic[8] = {0x89, 'L', 'T', 'M', '\r', '\n', 0x1a, '\n'};
  std::memcpy(&b[0], magic, 8);                                                      // magic
  Put16(b, 8, major);                                                                // format major
  Put16(b, 10, minor);                                                               // format minor
  Put32(b, 12, 64);                                                                  // header size
  Put64(b, 16, required);                                                            // required-feature flags
  Put64(b, 24, 0);                                                                   // optional-feature flags
  Put64(b, 32, meta_len_override >= 0 ? uint64_t(meta_len_override) : meta.size());  // metadata length
  Put64(b, 40, XXH3_64bits(meta.data(), meta.size()));                               // metadata checksum
  Put64(b, 48, 0);                                                                   // reserved
  Seal56(b, 0);                                                                      // header checksum
  std::memcpy(&b[64], meta.data(), meta.size());
  return b;
}

// A frame header for `payload` with the given fields, then the payload padded to 64.
void AppendFrame(Bytes& b, uint16_t type, uint16_t flags, uint32_t array, uint16_t encoding, uint64_t chunk,
                 const Bytes& payload, uint64_t decoded_length,
                 std::optional<uint64_t> payload_len_override = std::nullopt) {
  size_t at = b.size();
  b.resize(at + 64 + (payload.size() + 63) / 64 * 64, 0);
  Put32(b, at + 0, 0x464D544C);                                     // "LTMF"
  Put16(b, at + 4, type);                                           // frame type
  Put16(b, at + 6, flags);                                          // flags (1 = optional)
  Put64(b, at + 8, payload_len_override.value_or(payload.size()));  // payload length
  Put32(b, at + 16, array);                                         // array id
  Put16(b, at + 20, encoding);                                      // encoding
  Put64(b, at + 24, chunk);                                         // chunk index
  Put64(b, at + 32, decoded_length);                                // decoded length
  Put64(b, at + 40, XXH3_64bits(payload.data(), payload.size()));   // payload checksum
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
  EXPECT_NE(s.message().find("reads up to 1.2"), std::string::npos) << s.message();  // 1.2: coded chunks
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

TEST(Version, MinorIsInformationalEncodingsAreCheckedPerChunk) {
  // A file labelled 1.0 holding a sparse chunk (a 1.0 file resumed by a 1.1 writer) reads:
  // readers go by each chunk's encoding, never by the header's minor.
  test::TempDir dir;
  Bytes b = Header(1, 0);
  AppendFrame(b, 1, 0, 0, 3, 0, {0x01, 0x02, 0x00, 0x00, 0x80, 0x3F}, 16);  // index 2 = 1.0f
  AppendFrame(b, 1, 0, 0, 1, 1, {}, 16);
  auto r = io::ContainerReader::Open(WriteFile(dir, b));
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_TRUE(r->complete());
  auto c = r->ReadChunk(0, 0);
  ASSERT_TRUE(c.ok()) << c.status().message();
  EXPECT_EQ(std::vector<float>(c->as<float>().begin(), c->as<float>().end()),
            std::vector<float>({0.0f, 0.0f, 1.0f, 0.0f}));
}

TEST(Version, RefusesUnknownEncodingAsNewer) {
  // What a 1.0 reader does with a sparse chunk (and a 1.1 reader with a coded one), this
  // build does with encoding 6: the file opens, that chunk is refused (reported, never
  // read as data), the others read.
  test::TempDir dir;
  Bytes b = Header(1, 9);
  AppendFrame(b, 1, 0, 0, 6, 0, {0x01, 0x02, 0x03}, 16);
  AppendFrame(b, 1, 0, 0, 0, 1, RawChunk(5), 16);
  auto path = WriteFile(dir, b);
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_EQ(r->committed(0), 1u);
  ASSERT_EQ(r->problems().size(), 1u);
  EXPECT_NE(r->problems()[0].find("unknown chunk encoding 6 (written by a newer ltbake?)"), std::string::npos)
      << r->problems()[0];
  EXPECT_EQ(r->ReadChunk(0, 0).status().code(), StatusCode::kNotFound);
  EXPECT_TRUE(r->ReadChunk(0, 1).ok());
  auto v = io::VerifyContainer(path);
  ASSERT_FALSE(v.problems.empty());
  EXPECT_NE(v.problems[0].find("unknown chunk encoding 6"), std::string::npos) << v.problems[0];
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
  auto w = io::ContainerWriter::Open(path, *ParseJson(meta));
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
  std::string meta =
      R"({"arrays":[{"block":1,"dtype":"f32","layout":"rows","name":"matrix","shape":[1099511627776,1]}]})";
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
  std::string meta =
      R"({"arrays":[{"block":1,"dtype":"f32","layout":"rows","name":"matrix","shape":[4,99999999999999]}]})";
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
  EXPECT_NE(r->problems()[0].find("index claims 1152921504606846976 entries"), std::string::npos) << r->problems()[0];
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

// ---- Sparse payloads (format 1.1), laid out by hand from docs/FORMAT.md ----

// One zstd frame of `bytes` (EncodeChunk's zstd candidate, accepted at any size).
Bytes Zstd(const Bytes& bytes) {
  format::EncodeOptions eo;
  eo.detect_zero = false;
  eo.zstd = true;
  eo.min_saving = -1e9;
  auto c = format::EncodeChunk(format::ByteSpan(reinterpret_cast<const std::byte*>(bytes.data()), bytes.size()), eo);
  auto p = reinterpret_cast<const unsigned char*>(c.payload.data());
  return Bytes(p, p + c.payload.size());
}

Bytes DropLast(Bytes b, size_t n) {
  b.resize(b.size() - n);
  return b;
}

Bytes Cat(std::initializer_list<Bytes> parts) {
  Bytes out;
  for (const Bytes& p : parts) out.insert(out.end(), p.begin(), p.end());
  return out;
}

const Bytes kOne = {0x00, 0x00, 0x80, 0x3F};  // 1.0f

TEST(Sparse, HandBuiltChunksRead) {
  test::TempDir dir;
  // Chunk 0 (rows 0-1, row-major): index 1 = 1.0f, index 3 = -0.0f. Chunk 1: the same
  // payload as a zstd frame.
  Bytes payload = Cat({{0x02, 0x01, 0x01}, kOne, {0x00, 0x00, 0x00, 0x80}});
  Bytes b = Header(1, 1);
  AppendFrame(b, 1, 0, 0, 3, 0, payload, 16);
  AppendFrame(b, 1, 0, 0, 4, 1, Zstd(payload), 16);
  auto path = WriteFile(dir, b);
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_TRUE(r->complete());
  for (uint64_t i = 0; i < 2; ++i) {
    auto c = r->ReadChunk(0, i);
    ASSERT_TRUE(c.ok()) << c.status().message();
    uint32_t bits[4];
    std::memcpy(bits, c->bytes().data(), 16);
    EXPECT_EQ(bits[0], 0u);
    EXPECT_EQ(bits[1], 0x3F800000u);
    EXPECT_EQ(bits[2], 0u);
    EXPECT_EQ(bits[3], 0x80000000u);
    auto s = r->ReadSparse(0, i);
    ASSERT_TRUE(s.ok()) << s.status().message();
    EXPECT_EQ(s->index, std::vector<uint32_t>({1, 3}));
    EXPECT_EQ(s->extent.row0, 2 * i);
  }
  auto v = io::VerifyContainer(path);
  EXPECT_TRUE(v.problems.empty()) << v.problems.front();
  EXPECT_EQ(v.chunks_ok, 2u);
  EXPECT_FALSE(v.sealed);  // hand-built: no index, no trailer
  auto sum = io::SummarizeArray(*r, 0, 1);
  ASSERT_TRUE(sum.ok()) << sum.status().message();
  EXPECT_EQ(sum->stats.count, 8u);
}

TEST(Sparse, ColumnChunksIndexColumnMajor) {
  test::TempDir dir;
  std::string meta = R"({"arrays":[{"block":3,"dtype":"f32","layout":"cols","name":"matrix","shape":[2,3]}]})";
  Bytes b = Header(1, 1, 0, meta);
  AppendFrame(b, 1, 0, 0, 3, 0, Cat({{0x01, 0x05}, kOne}), 24);  // index 5 = column 2 * 2 rows + row 1
  auto r = io::ContainerReader::Open(WriteFile(dir, b));
  ASSERT_TRUE(r.ok()) << r.status().message();
  auto c = r->ReadChunk(0, 0);
  ASSERT_TRUE(c.ok()) << c.status().message();
  EXPECT_EQ(c->as<float>()[5], 1.0f);
  auto s = r->ReadSparse(0, 0);
  ASSERT_TRUE(s.ok());
  EXPECT_EQ(s->index, std::vector<uint32_t>({5}));
}

struct BadSparse {
  const char* name;
  std::string dtype;
  uint16_t encoding;
  Bytes payload;
  const char* expect;  // in the DataLoss message
};

class MalformedSparse : public ::testing::TestWithParam<BadSparse> {};

// Chunk 0 holds the malformed payload (checksums valid), chunk 1 is fine.
TEST_P(MalformedSparse, IsDataLossNamingChunkAndFault) {
  const BadSparse& p = GetParam();
  test::TempDir dir;
  std::string meta =
      R"({"arrays":[{"block":2,"dtype":")" + p.dtype + R"(","layout":"rows","name":"matrix","shape":[4,2]}]})";
  uint64_t bytes = p.dtype == "u8" ? 4 : 16;
  Bytes b = Header(1, 1, 0, meta);
  AppendFrame(b, 1, 0, 0, p.encoding, 0, p.payload, bytes);
  AppendFrame(b, 1, 0, 0, 1, 1, {}, bytes);
  auto path = WriteFile(dir, b);
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_TRUE(r->complete());  // the frame is intact; its payload is what is wrong
  for (int sparse = 0; sparse < 2; ++sparse) {
    Status s = sparse ? r->ReadSparse(0, 0).status() : r->ReadChunk(0, 0).status();
    EXPECT_EQ(s.code(), StatusCode::kDataLoss) << s.message();
    EXPECT_NE(s.message().find(path + ": array \"matrix\" chunk 0 (rows 0-1)"), std::string::npos) << s.message();
    EXPECT_NE(s.message().find(p.expect), std::string::npos) << s.message();
  }
  EXPECT_TRUE(r->ReadChunk(0, 1).ok());
  auto sum = io::SummarizeArray(*r, 0, 1);
  EXPECT_EQ(sum.status().code(), StatusCode::kDataLoss);
  auto v = io::VerifyContainer(path);
  EXPECT_FALSE(v.complete);
  EXPECT_EQ(v.chunks_ok, 1u);
  ASSERT_EQ(v.problems.size(), 1u);
  EXPECT_NE(v.problems[0].find("(array \"matrix\" chunk 0)"), std::string::npos) << v.problems[0];
  EXPECT_NE(v.problems[0].find(p.expect), std::string::npos) << v.problems[0];
}

const Bytes kGood = Cat({{0x01, 0x00}, kOne});

INSTANTIATE_TEST_SUITE_P(
    Payloads, MalformedSparse,
    ::testing::Values(
        BadSparse{"truncated_count", "f32", 3, {0x81}, "payload ends inside the element count"},
        BadSparse{"count_above_elements", "f32", 3, Cat({{0x05, 0, 0, 0, 0, 0}, kOne, kOne, kOne, kOne, kOne}),
                  "stores 5 elements, the chunk has 4"},
        BadSparse{
            "huge_count", "f32", 3, {0xFF, 0xFF, 0xFF, 0xFF, 0x0F}, "stores 4294967295 elements, the chunk has 4"},
        BadSparse{"varint_over_64_bits", "f32", 3,
                  Cat({{0x01, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x02}, kOne}),
                  "varint longer than 64 bits at byte 1"},
        BadSparse{"non_canonical_varint", "f32", 3, Cat({{0x01, 0x80, 0x00}, kOne}), "non-canonical varint"},
        BadSparse{"index_out_of_range", "f32", 3, Cat({{0x01, 0x04}, kOne}), "past the chunk's 4 elements"},
        BadSparse{"second_index_out_of_range", "f32", 3, Cat({{0x02, 0x02, 0x01}, kOne, kOne}),
                  "index 1 of 2 (gap 1 after position 3) is past the chunk's 4 elements"},
        BadSparse{"index_wraps_around", "f32", 3,
                  Cat({{0x02, 0x01, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0xFF, 0x01}, kOne, kOne}),
                  "index 1 of 2 (gap 18446744073709551615"},
        BadSparse{"missing_index", "f32", 3, {0x02, 0x00}, "payload ends inside index 1 of 2"},
        BadSparse{"missing_value_bytes", "f32", 3, {0x01, 0x00, 0x00, 0x00, 0x80}, "payload ends inside value 0 of 1"},
        BadSparse{"trailing_bytes", "f32", 3, Cat({kGood, {0x00}}), "trailing bytes after the last value, from byte 6"},
        BadSparse{"zero_value", "f32", 3, {0x01, 0x00, 0x00, 0x00, 0x00, 0x00}, "value 0 of 1 is zero"},
        BadSparse{"i32_value_too_large", "i32", 3, {0x01, 0x00, 0xFF, 0xFF, 0xFF, 0xFF, 0x1F}, "too large for i32"},
        BadSparse{"u8_value_too_large", "u8", 3, {0x01, 0x00, 0x80, 0x02}, "value 0 of 1 is 256, too large for u8"},
        BadSparse{"u8_zero_value", "u8", 3, {0x01, 0x00, 0x00}, "value 0 of 1 is zero"},
        BadSparse{"zstd_not_a_frame", "f32", 4, {1, 2, 3, 4, 5, 6, 7, 8}, "zstd: "},
        BadSparse{"zstd_truncated", "f32", 4, DropLast(Zstd(kGood), 3), "zstd"},
        BadSparse{"zstd_trailing_bytes", "f32", 4, Cat({Zstd(kGood), {0x00}}), "trailing bytes after its frame"},
        BadSparse{"zstd_of_zero_value", "f32", 4, Zstd({0x01, 0x00, 0x00, 0x00, 0x00, 0x00}), "value 0 of 1 is zero"},
        BadSparse{"zstd_of_short_payload", "f32", 4, Zstd({0x02, 0x00, 0x00}), "payload ends inside value 0 of 2"},
        BadSparse{"zstd_of_long_payload", "f32", 4, Zstd(Cat({kGood, kOne})), "trailing bytes after the last value"}),
    [](const ::testing::TestParamInfo<BadSparse>& info) { return std::string(info.param.name); });

TEST(Sparse, EmptyPayloadIsNotCommitted) {
  test::TempDir dir;
  Bytes b = Header(1, 1);
  AppendFrame(b, 1, 0, 0, 3, 0, {}, 16);
  AppendFrame(b, 1, 0, 0, 4, 1, {}, 16);
  auto path = WriteFile(dir, b);
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_EQ(r->committed(0), 0u);
  ASSERT_EQ(r->problems().size(), 2u);
  EXPECT_NE(r->problems()[0].find("sparse chunk with an empty payload"), std::string::npos) << r->problems()[0];
  EXPECT_NE(r->problems()[1].find("sparse-zstd chunk with an empty payload"), std::string::npos) << r->problems()[1];
  auto v = io::VerifyContainer(path);
  EXPECT_EQ(v.problems.size(), 2u);
}

TEST(Sparse, OversizedSparseChunkIsRefusedBeforeAllocating) {
  // One u8 chunk of 2^33 elements (8 GiB) stored sparse: its indices cannot be 32-bit.
  test::TempDir dir;
  std::string meta =
      R"({"arrays":[{"block":8589934592,"dtype":"u8","layout":"cols","name":"matrix","shape":[1,8589934592]}]})";
  Bytes b = Header(1, 1, 0, meta);
  AppendFrame(b, 1, 0, 0, 3, 0, {0x00}, uint64_t(1) << 33);
  auto path = WriteFile(dir, b);
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok()) << r.status().message();
  for (int sparse = 0; sparse < 2; ++sparse) {
    Status s = sparse ? r->ReadSparse(0, 0).status() : r->ReadChunk(0, 0).status();
    EXPECT_EQ(s.code(), StatusCode::kDataLoss);
    EXPECT_NE(s.message().find("a chunk of 8589934592 elements cannot be sparse (at most 4294967295)"),
              std::string::npos)
        << s.message();
  }
  auto v = io::VerifyContainer(path);
  ASSERT_EQ(v.problems.size(), 1u);
  EXPECT_NE(v.problems[0].find("cannot be sparse"), std::string::npos) << v.problems[0];
}

// ---- Coded sparse payloads (encoding 5, format 1.2) in hand-built frames ----

// An i32 column array of 8 x 2, one column per chunk (lines of L = 8).
const std::string kCodedMeta =
    R"({"arrays":[{"block":1,"dtype":"i32","layout":"cols","name":"matrix","shape":[8,2]}]})";
const std::vector<int32_t> kCodedColumn = {0, 3, 0, 0, -1, 0, 0, 2};

Bytes CodedPayload(const std::vector<int32_t>& v, uint64_t line, uint64_t width) {
  auto p = format::EncodeCodedPayload(format::ByteSpan(reinterpret_cast<const std::byte*>(v.data()), 4 * v.size()),
                                      line, width);
  auto u = reinterpret_cast<const unsigned char*>(p.data());
  return Bytes(u, u + p.size());
}

TEST(Coded, HandBuiltChunkReads) {
  test::TempDir dir;
  Bytes payload = CodedPayload(kCodedColumn, 8, 4);
  ASSERT_EQ(payload[0], 1);  // model
  ASSERT_EQ(payload[1], 4);  // W
  Bytes b = Header(1, 2, 0, kCodedMeta);
  AppendFrame(b, 1, 0, 0, 5, 0, payload, 32);
  AppendFrame(b, 1, 0, 0, 1, 1, {}, 32);
  auto path = WriteFile(dir, b);
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_TRUE(r->complete());
  auto c = r->ReadChunk(0, 0);
  ASSERT_TRUE(c.ok()) << c.status().message();
  EXPECT_EQ(std::vector<int32_t>(c->as<int32_t>().begin(), c->as<int32_t>().end()), kCodedColumn);
  auto s = r->ReadSparse(0, 0);
  ASSERT_TRUE(s.ok()) << s.status().message();
  EXPECT_EQ(s->index, std::vector<uint32_t>({1, 4, 7}));
  auto v = io::VerifyContainer(path);
  EXPECT_TRUE(v.problems.empty()) << v.problems.front();
  EXPECT_EQ(v.chunks_ok, 2u);
}

struct BadCoded {
  const char* name;
  std::string meta;
  Bytes payload;
  const char* expect;
};

class MalformedCoded : public ::testing::TestWithParam<BadCoded> {};

// Chunk 0 holds the malformed payload (checksums valid), chunk 1 is all zero.
TEST_P(MalformedCoded, IsDataLossNamingChunkAndFault) {
  const BadCoded& p = GetParam();
  test::TempDir dir;
  Bytes b = Header(1, 2, 0, p.meta);
  AppendFrame(b, 1, 0, 0, 5, 0, p.payload, 32);
  AppendFrame(b, 1, 0, 0, 1, 1, {}, 32);
  auto path = WriteFile(dir, b);
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_TRUE(r->complete());
  for (int sparse = 0; sparse < 2; ++sparse) {
    Status s = sparse ? r->ReadSparse(0, 0).status() : r->ReadChunk(0, 0).status();
    EXPECT_EQ(s.code(), StatusCode::kDataLoss) << s.message();
    EXPECT_NE(s.message().find("chunk 0"), std::string::npos) << s.message();
    EXPECT_NE(s.message().find(p.expect), std::string::npos) << s.message();
  }
  EXPECT_TRUE(r->ReadChunk(0, 1).ok());
  auto v = io::VerifyContainer(path);
  EXPECT_EQ(v.chunks_ok, 1u);
  ASSERT_EQ(v.problems.size(), 1u);
  EXPECT_NE(v.problems[0].find(p.expect), std::string::npos) << v.problems[0];
}

Bytes With(Bytes b, size_t at, unsigned char v) {
  b[at] = v;
  return b;
}

const Bytes kCodedGood = CodedPayload(kCodedColumn, 8, 4);

INSTANTIATE_TEST_SUITE_P(
    Payloads, MalformedCoded,
    ::testing::Values(
        BadCoded{"unknown_model", kCodedMeta, With(kCodedGood, 0, 2), "unknown model 2"},
        BadCoded{"width_zero", kCodedMeta, With(kCodedGood, 1, 0), "image width 0 is not in 1..8"},
        BadCoded{"width_above_line", kCodedMeta, With(kCodedGood, 1, 9), "image width 9 is not in 1..8"},
        BadCoded{"width_truncated", kCodedMeta, {0x01, 0x84}, "ends inside the image width"},
        BadCoded{"coder_too_short", kCodedMeta, {0x01, 0x04, 0x00, 0x00}, "the coder's bytes end after 2 bytes"},
        BadCoded{"coder_first_byte", kCodedMeta, With(kCodedGood, 2, 7), "the coder's first byte is not 0"},
        BadCoded{"truncated", kCodedMeta, DropLast(kCodedGood, 1), "truncated"},
        BadCoded{"trailing_byte", kCodedMeta, Cat({kCodedGood, {0x00}}), "1 trailing bytes"},
        // The same bytes in an f32 array, and in an i32 array whose lines are rows of 2.
        BadCoded{"f32_array", R"({"arrays":[{"block":1,"dtype":"f32","layout":"cols","name":"matrix","shape":[8,2]}]})",
                 kCodedGood, "a sparse-coded chunk in a f32 array"},
        BadCoded{"rows_of_two",
                 R"({"arrays":[{"block":4,"dtype":"i32","layout":"rows","name":"matrix","shape":[8,2]}]})", kCodedGood,
                 "image width 4 is not in 1..2"}),
    [](const ::testing::TestParamInfo<BadCoded>& info) { return std::string(info.param.name); });

TEST(Coded, LineLongerThanTheFormatAllowsIsRefusedBeforeAllocating) {
  // One i32 column of 2^24 + 1 rows (64 MiB) claimed coded: refused from the metadata alone.
  test::TempDir dir;
  std::string meta = R"({"arrays":[{"block":1,"dtype":"i32","layout":"cols","name":"matrix","shape":[16777217,1]}]})";
  Bytes b = Header(1, 2, 0, meta);
  AppendFrame(b, 1, 0, 0, 5, 0, kCodedGood, uint64_t{4} * 16777217);
  auto path = WriteFile(dir, b);
  auto r = io::ContainerReader::Open(path);
  ASSERT_TRUE(r.ok()) << r.status().message();
  for (int sparse = 0; sparse < 2; ++sparse) {
    Status s = sparse ? r->ReadSparse(0, 0).status() : r->ReadChunk(0, 0).status();
    EXPECT_EQ(s.code(), StatusCode::kDataLoss);
    EXPECT_NE(s.message().find("with lines of 16777217 elements (at most 16777216)"), std::string::npos) << s.message();
  }
  auto v = io::VerifyContainer(path);
  ASSERT_EQ(v.problems.size(), 1u);
  EXPECT_NE(v.problems[0].find("lines of 16777217"), std::string::npos) << v.problems[0];
}

TEST(Coded, EmptyPayloadIsNotCommitted) {
  test::TempDir dir;
  Bytes b = Header(1, 2, 0, kCodedMeta);
  AppendFrame(b, 1, 0, 0, 5, 0, {}, 32);
  auto r = io::ContainerReader::Open(WriteFile(dir, b));
  ASSERT_TRUE(r.ok()) << r.status().message();
  EXPECT_EQ(r->committed(0), 0u);
  ASSERT_EQ(r->problems().size(), 1u);
  EXPECT_NE(r->problems()[0].find("sparse-coded chunk with an empty payload"), std::string::npos) << r->problems()[0];
}

}  // namespace
}  // namespace ltb
