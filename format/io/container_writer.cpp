#include "format/io/container_writer.h"

#include <unistd.h>

#include <cerrno>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <tuple>

#include "format/coded_codec.h"
#include "format/content_hash.h"
#include "format/io/atomic_file.h"
#include "format/io/container_reader.h"
#include "format/io/frame_scan.h"
#include "format/io/io_trace.h"
#include "format/json_text.h"
#include "format/version.h"

namespace ltb::io {

using namespace ltb::format;

ContainerWriter::ContainerWriter(ContainerWriter&& o) noexcept { *this = std::move(o); }

ContainerWriter& ContainerWriter::operator=(ContainerWriter&& o) noexcept {
  if (this != &o) {
    direct_ = File();  // the old file's descriptors close before its lock goes
    file_ = std::move(o.file_);
    lock_ = std::move(o.lock_);
    resumed_reader_ = std::move(o.resumed_reader_);
    metadata_ = std::move(o.metadata_);
    header_ = o.header_;
    resume_ = o.resume_;
    options_ = o.options_;
    end_ = o.end_;
    sealed_ = o.sealed_;
    mutations_ = o.mutations_;
    frames_ = std::move(o.frames_);
    committed_ = std::move(o.committed_);
    hash_sums_ = std::move(o.hash_sums_);
    hashed_ = std::move(o.hashed_);
    direct_ = std::move(o.direct_);
    bounce_ = std::move(o.bounce_);
    direct_stats_ = std::move(o.direct_stats_);
  }
  return *this;
}

ContainerWriter::~ContainerWriter() = default;

void ContainerWriter::FreeDeleter::operator()(std::byte* p) const { std::free(p); }

namespace {
constexpr uint64_t kBounceBytes = 1 << 20;  // staging buffer for payloads not 4096-aligned in memory
}  // namespace

DirectIoStats ContainerWriter::direct_io_stats() const {
  std::lock_guard<std::mutex> lock(mu_);
  DirectIoStats s = direct_stats_;
  s.active = direct_.fd() >= 0;
  return s;
}

void ContainerWriter::OpenDirect() {
  if (!options_.direct_io || sealed_ || file_.fd() < 0) return;
  auto f = File::Open(file_.path(), File::Mode::kWriteDirect);
  if (!f.ok()) {
    direct_stats_.fallback_reason = "O_DIRECT open refused: " + f.status().message();
    return;
  }
  direct_ = std::move(f).value();
}

namespace {

// Writes header + metadata to a temporary file and renames it into place, so the path
// never holds a half-written header.
Status CreateFile(const std::string& path, const std::string& metadata_bytes) {
  ByteSpan mb(reinterpret_cast<const std::byte*>(metadata_bytes.data()), metadata_bytes.size());
  FileHeader h;
  h.major = kFormatMajor;
  h.minor = kFormatMinor;
  h.metadata_length = mb.size();
  h.metadata_checksum = Checksum(mb);
  auto hb = EncodeFileHeader(h);
  LTB_ASSIGN_OR_RETURN(AtomicFile f, AtomicFile::Create(path));
  LTB_RETURN_IF_ERROR(f.file().WriteAt(0, hb));
  LTB_RETURN_IF_ERROR(f.file().WriteAt(kHeaderSize, mb));
  LTB_RETURN_IF_ERROR(f.file().Truncate(h.FirstFrameOffset()));  // zero padding up to the first frame
  return f.Commit();
}

// Names the first top-level metadata key whose value differs.
std::string FirstKeyDifference(const nlohmann::json& file, const nlohmann::json& wanted) {
  for (auto it = wanted.begin(); it != wanted.end(); ++it) {
    if (!file.contains(it.key())) return "key \"" + it.key() + "\" is not in the file";
    if (file[it.key()] != it.value()) {
      std::string a = JsonText(file[it.key()]), b = JsonText(it.value());
      if (a.size() > 200) a = a.substr(0, 200) + "...";
      if (b.size() > 200) b = b.substr(0, 200) + "...";
      return "\"" + it.key() + "\": file has " + a + ", this run wants " + b;
    }
  }
  for (auto it = file.begin(); it != file.end(); ++it) {
    if (!wanted.contains(it.key())) return "the file has key \"" + it.key() + "\", this run does not";
  }
  return "metadata differs";
}

}  // namespace

Result<ContainerWriter> ContainerWriter::Open(const std::string& path, const nlohmann::json& metadata,
                                              const WriterOptions& options) {
  auto parsed = MetadataFromJson(metadata);
  if (!parsed.ok()) return parsed.status().WithContext(path);
  std::string bytes = SerializeMetadata(metadata);
  if (bytes.size() > kMaxMetadataBytes) {
    return InvalidArgument(path + ": metadata is " + std::to_string(bytes.size()) + " bytes, over the cap of " +
                           std::to_string(kMaxMetadataBytes));
  }

  ContainerWriter w;
  w.options_ = options;
  w.metadata_ = std::move(parsed).value();
  w.hash_sums_.assign(w.metadata_.arrays.size(), 0);
  // Before anything at path is opened: a second writer stops here.
  LTB_ASSIGN_OR_RETURN(w.lock_, LockOutput(path));

  if (PathExists(path)) {
    LTB_ASSIGN_OR_RETURN(File f, File::Open(path, File::Mode::kReadWrite));
    LTB_ASSIGN_OR_RETURN(uint64_t size, f.Size());
    auto prelude = ReadPrelude(f, size);
    if (!prelude.ok()) {
      if (prelude.status().code() == StatusCode::kUnimplemented) return prelude.status().WithContext(path);
      if (!options.overwrite_mismatch) {
        return FailedPrecondition(path + ": exists and is not a readable .ltm container (" +
                                  prelude.status().message() + "); remove it or choose another output path");
      }
    } else if (prelude->metadata_bytes != bytes) {
      if (!options.overwrite_mismatch) {
        return FailedPrecondition(path + ": exists and was written with other parameters (" +
                                  FirstKeyDifference(prelude->metadata.json, metadata) +
                                  "); remove it, or rerun with --overwrite to replace it");
      }
    } else {
      w.file_ = std::move(f);
      w.header_ = prelude->header;
      Status s = w.Resume(size);
      if (!s.ok()) return s.WithContext(path);
      w.OpenDirect();
      return w;
    }
  }
  LTB_RETURN_IF_ERROR(CreateFile(path, bytes));
  LTB_ASSIGN_OR_RETURN(w.file_, File::Open(path, File::Mode::kReadWrite));
  LTB_ASSIGN_OR_RETURN(uint64_t size, w.file_.Size());
  auto prelude = ReadPrelude(w.file_, size);
  if (!prelude.ok()) return prelude.status().WithContext(path + " (just created)");
  w.header_ = prelude->header;
  w.end_ = w.header_.FirstFrameOffset();
  w.OpenDirect();
  return w;
}

Status ContainerWriter::Resume(uint64_t file_size) {
  resume_.resumed = true;
  LTB_ASSIGN_OR_RETURN(ScanResult scan, ScanFrames(file_, header_.FirstFrameOffset(), file_size));
  if (!scan.gaps.empty()) {
    return DataLoss("damaged at offset " + std::to_string(scan.gaps.front().offset) + " (" + scan.gaps.front().reason +
                    ") with committed chunks after it; refusing to append. Run `ltbake verify " + file_.path() +
                    "` and remove the file to start over");
  }
  uint64_t end = header_.FirstFrameOffset();
  bool saw_index = false;
  for (const IndexEntry& e : scan.frames) {
    if (e.header.type == static_cast<uint16_t>(FrameType::kIndex)) {
      saw_index = true;
      break;  // frames after an index are not expected; the seal is redone below
    }
    // A content-hash frame is written only when sealing: one before the end of the log is
    // from an interrupted seal, and is cut off with it (sealing writes it again).
    if (e.header.type == static_cast<uint16_t>(FrameType::kContentHash)) continue;
    end = e.frame_offset + e.header.FrameSize();
    if (e.header.type != static_cast<uint16_t>(FrameType::kChunk)) continue;
    const FrameHeader& h = e.header;
    if (h.array >= metadata_.arrays.size() || h.chunk_index >= metadata_.arrays[h.array].ChunkCount()) {
      return DataLoss("frame at offset " + std::to_string(e.frame_offset) + " names a chunk outside the metadata");
    }
    LTB_RETURN_IF_ERROR(CheckChunkLengths(h, metadata_.arrays[h.array].ChunkBytes(h.chunk_index))
                            .WithContext("frame at offset " + std::to_string(e.frame_offset)));
    if (committed_.insert(Key(h.array, h.chunk_index)).second) frames_.push_back(e);
  }
  resume_.committed_chunks = frames_.size();
  // Sealed and intact: nothing to do.
  if (saw_index && file_size >= kTrailerSize) {
    std::array<std::byte, kTrailerSize> tb;
    LTB_RETURN_IF_ERROR(file_.ReadAt(file_size - kTrailerSize, tb));
    if (DecodeTrailer(tb, file_size).ok()) {
      sealed_ = true;
      resume_.already_complete = true;
      end_ = file_size;
      return Status::Ok();
    }
  }
  // Cut off the uncommitted tail (a chunk in flight when the writer stopped, or an
  // interrupted seal); the next frame goes where the last committed one ended.
  end_ = end;
  if (file_size > end_) {
    resume_.discarded_tail_bytes = file_size - end_;
    LTB_RETURN_IF_ERROR(file_.Truncate(end_));
  }
  return Status::Ok();
}

Status ContainerWriter::CountMutation() {
  if (mutations_ >= options_.stop_after_mutations) {
    return Internal(path() + ": stopped after " + std::to_string(mutations_) + " writes (stop_after_mutations)");
  }
  ++mutations_;
  return Status::Ok();
}

bool ContainerWriter::Has(uint32_t array, uint64_t chunk) const {
  std::lock_guard<std::mutex> lock(mu_);
  return committed_.count(Key(array, chunk)) != 0;
}

std::vector<uint64_t> ContainerWriter::Missing(uint32_t array) const {
  std::lock_guard<std::mutex> lock(mu_);
  std::vector<uint64_t> out;
  uint64_t b = 0, n = metadata_.arrays.at(array).ChunkCount();
  if (metadata_.shard) std::tie(b, n) = metadata_.shard->chunks.at(array);
  for (uint64_t i = b; i < n; ++i)
    if (committed_.count(Key(array, i)) == 0) out.push_back(i);
  return out;
}

namespace {

// The chunk's place (its array, its index, this shard's share) and its encoding (decoded
// size, a coded or sparse payload's dtype and line length), before anything is written.
Status CheckChunkFits(const std::string& path, const format::Metadata& m, uint32_t array, uint64_t chunk,
                      const EncodedChunk& encoded) {
  if (array >= m.arrays.size()) return InvalidArgument(path + ": no array " + std::to_string(array));
  const ArraySpec& a = m.arrays[array];
  if (chunk >= a.ChunkCount()) {
    return InvalidArgument(path + ": chunk " + std::to_string(chunk) + " of array \"" + a.name + "\" out of range (" +
                           std::to_string(a.ChunkCount()) + " chunks)");
  }
  if (!m.Owns(array, chunk)) {
    const auto& [b, e] = m.shard->chunks[array];
    return InvalidArgument(path + ": chunk " + std::to_string(chunk) + " of array \"" + a.name +
                           "\" does not belong to shard " + std::to_string(m.shard->index) + " of " +
                           std::to_string(m.shard->count) + " (it owns chunks " + std::to_string(b) + "-" +
                           std::to_string(e) + ")");
  }
  if (encoded.decoded_length != a.ChunkBytes(chunk)) {
    return InvalidArgument(path + ": chunk " + std::to_string(chunk) + " of array \"" + a.name + "\" has " +
                           std::to_string(encoded.decoded_length) + " bytes, expected " +
                           std::to_string(a.ChunkBytes(chunk)));
  }
  if (encoded.encoding == Encoding::kCoded) {
    // A coded payload is read back as i32 lines of the array's line length.
    const uint64_t line = CodedLineLength(a.layout, a.Extent(chunk));
    if (encoded.dtype != DType::kI32 || a.dtype != DType::kI32 || encoded.line_length != line) {
      return InvalidArgument(path + ": chunk " + std::to_string(chunk) + " of array \"" + a.name + "\" was coded as " +
                             DTypeName(encoded.dtype) + " lines of " + std::to_string(encoded.line_length) +
                             ", the array is " + DTypeName(a.dtype) + " with lines of " + std::to_string(line));
    }
  }
  if (encoded.encoding == Encoding::kSparse || encoded.encoding == Encoding::kSparseZstd ||
      encoded.encoding == Encoding::kCoded) {
    // A sparse payload is read back with the array's dtype and 32-bit indices.
    if (encoded.dtype != a.dtype) {
      return InvalidArgument(path + ": chunk " + std::to_string(chunk) + " of array \"" + a.name +
                             "\" was sparse-encoded as " + DTypeName(encoded.dtype) + ", the array is " +
                             DTypeName(a.dtype));
    }
    if (a.Extent(chunk).Elements() > kMaxSparseElements) {
      return InvalidArgument(path + ": chunk " + std::to_string(chunk) + " of array \"" + a.name + "\" has " +
                             std::to_string(a.Extent(chunk).Elements()) +
                             " elements, more than a sparse chunk holds (" + std::to_string(kMaxSparseElements) + ")");
    }
  }
  return Status::Ok();
}

}  // namespace

Status ContainerWriter::Append(uint32_t array, uint64_t chunk, const EncodedChunk& encoded,
                               std::optional<uint64_t> hash_sum) {
  LTB_RETURN_IF_ERROR(CheckChunkFits(path(), metadata_, array, chunk, encoded));
  const ArraySpec& a = metadata_.arrays[array];
  if (!hash_sum) {
    // Decoded here, outside the lock, as a reader would decode it.
    if (encoded.encoding == Encoding::kZero) {
      hash_sum = 0;
    } else if (encoded.encoding == Encoding::kRaw) {
      hash_sum = ChunkHashSum(a, a.Extent(chunk), encoded.payload);
    } else {
      std::vector<std::byte> dense(encoded.decoded_length);
      Status d = encoded.encoding == Encoding::kZstd     ? DecodeZstd(encoded.payload, dense)
                 : encoded.encoding == Encoding::kSparse ? DecodeSparseInto(encoded.payload, a.dtype, dense)
                 : encoded.encoding == Encoding::kSparseZstd
                     ? DecodeSparseZstdInto(encoded.payload, a.dtype, dense)
                     : DecodeCodedInto(encoded.payload, CodedLineLength(a.layout, a.Extent(chunk)), dense);
      if (!d.ok()) {
        return InvalidArgument(path() + ": chunk " + std::to_string(chunk) + " of array \"" + a.name +
                               "\" does not decode: " + d.message());
      }
      hash_sum = ChunkHashSum(a, a.Extent(chunk), dense);
    }
  }
  FrameHeader h;
  h.type = static_cast<uint16_t>(FrameType::kChunk);
  h.payload_length = encoded.payload.size();
  h.array = array;
  h.encoding = static_cast<uint16_t>(encoded.encoding);
  h.chunk_index = chunk;
  h.decoded_length = encoded.decoded_length;
  h.payload_checksum = encoded.checksum;
  auto hb = EncodeFrameHeader(h);
  static const std::array<std::byte, kAlignment> kZeros{};

  std::lock_guard<std::mutex> lock(mu_);
  if (sealed_) return FailedPrecondition(path() + ": is sealed; no chunk can be added");
  if (committed_.count(Key(array, chunk)) != 0) {
    return FailedPrecondition(path() + ": chunk " + std::to_string(chunk) + " of array \"" + a.name +
                              "\" is already committed");
  }
  uint64_t offset = end_;
  // A failed write names the chunk; what was committed before it stays committed.
  auto in_chunk = [&](const Status& s) {
    return Status(s.code(), "writing chunk " + std::to_string(chunk) + " of array \"" + a.name + "\": " + s.message());
  };
  const bool direct = direct_.fd() >= 0 && h.payload_length >= options_.direct_min_bytes;
  if (direct) {
    // The payload (at frame + 64) goes on a kDirectAlignment boundary; a padding frame
    // fills the gap (frames are 64-aligned, so the gap is 0 or at least one header).
    const uint64_t frame = AlignUp(offset + kFrameHeaderSize, kDirectAlignment) - kFrameHeaderSize;
    if (frame != offset) {
      if (Status s = AppendPadding(frame); !s.ok()) return in_chunk(s);
      offset = frame;
    }
  }
  // Payload and its zero padding first, the header last: the header write is the commit.
  // (Only a crash test turns the order round, to show its replay notices.)
  const bool header_first = BarrierSkipped(kBarrierHeaderLast);
  if (header_first) {
    if (Status s = file_.WriteAt(offset, hb); !s.ok()) return in_chunk(s);
  }
  if (Status s = WritePayload(offset + kFrameHeaderSize, encoded.payload, direct); !s.ok()) return in_chunk(s);
  uint64_t pad = AlignUp(h.payload_length, kAlignment) - h.payload_length;
  if (pad > 0) {
    LTB_RETURN_IF_ERROR(CountMutation());
    Status s = file_.WriteAt(offset + kFrameHeaderSize + h.payload_length, ByteSpan(kZeros.data(), pad));
    if (!s.ok()) return in_chunk(s);
  }
  if (options_.sync_each_chunk) {
    LTB_RETURN_IF_ERROR(CountMutation());
    if (Status s = file_.DataSync(); !s.ok()) return in_chunk(s);
  }
  LTB_RETURN_IF_ERROR(CountMutation());
  if (!header_first) {
    if (Status s = file_.WriteAt(offset, hb); !s.ok()) return in_chunk(s);
  }
  end_ = offset + h.FrameSize();
  frames_.push_back({offset, h});
  committed_.insert(Key(array, chunk));
  hash_sums_[array] += *hash_sum;
  hashed_.insert(Key(array, chunk));
  return Status::Ok();
}

// A padding frame from end_ to frame_offset: the file is zero-extended over it first, then
// its header is written (its payload is zeros), so a writer stopped in between leaves an
// uncommitted tail of zeros.
Status ContainerWriter::AppendPadding(uint64_t frame_offset) {
  static const std::array<std::byte, kDirectAlignment> kZeroPage{};
  FrameHeader p;
  p.type = static_cast<uint16_t>(FrameType::kPadding);
  p.flags = kFrameFlagOptional;
  p.payload_length = frame_offset - end_ - kFrameHeaderSize;
  p.decoded_length = p.payload_length;
  p.payload_checksum = Checksum(ByteSpan(kZeroPage.data(), p.payload_length));
  if (p.payload_length > 0) {
    LTB_RETURN_IF_ERROR(CountMutation());
    LTB_RETURN_IF_ERROR(file_.Truncate(frame_offset));
  }
  LTB_RETURN_IF_ERROR(CountMutation());
  LTB_RETURN_IF_ERROR(file_.WriteAt(end_, EncodeFrameHeader(p)));
  direct_stats_.padding_frames++;
  direct_stats_.padding_bytes += frame_offset - end_;
  end_ = frame_offset;
  return Status::Ok();
}

// Writes a payload at `offset`. Direct: the whole 4096-byte blocks go through the O_DIRECT
// descriptor (from the caller's memory when it is aligned, else through the staging
// buffer), the rest through the page cache. A file system that refuses O_DIRECT writes
// (EINVAL) turns direct writes off for the rest of the file.
Status ContainerWriter::WritePayload(uint64_t offset, ByteSpan payload, bool direct) {
  uint64_t done = 0;
  if (direct && offset % kDirectAlignment == 0) {
    const uint64_t whole = payload.size() / kDirectAlignment * kDirectAlignment;
    const bool aligned = reinterpret_cast<uintptr_t>(payload.data()) % kDirectAlignment == 0;
    if (!aligned && !bounce_) {
      bounce_.reset(static_cast<std::byte*>(std::aligned_alloc(kDirectAlignment, kBounceBytes)));
    }
    while (done < whole && direct_.fd() >= 0) {
      const uint64_t n = aligned ? whole - done : std::min(kBounceBytes, whole - done);
      ByteSpan piece = payload.subspan(done, n);
      if (!aligned) {
        if (!bounce_) break;  // no memory for staging: write through the page cache
        std::memcpy(bounce_.get(), piece.data(), n);
        piece = ByteSpan(bounce_.get(), n);
      }
      LTB_RETURN_IF_ERROR(CountMutation());
      int err = 0;
      uint64_t wrote = 0;
      while (wrote < n) {
        ssize_t r = ::pwrite(direct_.fd(), piece.data() + wrote, n - wrote, static_cast<off_t>(offset + done + wrote));
        if (r < 0 && errno == EINTR) continue;
        if (r <= 0) {
          err = r < 0 ? errno : EIO;
          break;
        }
        wrote += static_cast<uint64_t>(r);
      }
      if (err == EINVAL) {
        // The file system does not take this direct write (the kernel checks alignment
        // before writing anything): write through the page cache from here on.
        direct_stats_.fallback_reason = "O_DIRECT write refused (EINVAL) at offset " + std::to_string(offset + done);
        (void)direct_.Close();
        break;
      }
      if (err != 0) {
        return IoError(
            path() + ": direct write of " + std::to_string(n) + " bytes at offset " + std::to_string(offset + done),
            err);
      }
      if (Recording()) {
        RecordIo(
            {IoOp::Kind::kWrite, path(), {}, offset + done, std::vector<std::byte>(piece.begin(), piece.begin() + n)});
      }
      direct_stats_.direct_bytes += n;
      done += n;
    }
  }
  if (done < payload.size()) {
    LTB_RETURN_IF_ERROR(CountMutation());
    LTB_RETURN_IF_ERROR(file_.WriteAt(offset + done, payload.subspan(done)));
  }
  return Status::Ok();
}

Status ContainerWriter::Put(uint32_t array, uint64_t chunk, ByteSpan data, const EncodeOptions& options) {
  if (array >= metadata_.arrays.size()) return InvalidArgument(path() + ": no array " + std::to_string(array));
  const ArraySpec& a = metadata_.arrays[array];
  // The sum is taken from the bytes in hand (Append checks the chunk and its length).
  std::optional<uint64_t> sum;
  if (chunk < a.ChunkCount() && data.size() == a.ChunkBytes(chunk)) sum = ChunkHashSum(a, a.Extent(chunk), data);
  if (!options.sparse) {
    EncodedChunk c = EncodeChunk(data, options);
    return Append(array, chunk, c, sum);
  }
  if (chunk < a.ChunkCount() && a.Extent(chunk).Elements() > kMaxSparseElements) {
    return InvalidArgument(path() + ": chunk " + std::to_string(chunk) + " of array \"" + a.name + "\" has " +
                           std::to_string(a.Extent(chunk).Elements()) + " elements, more than a sparse chunk holds (" +
                           std::to_string(kMaxSparseElements) + "); use smaller chunks or no sparse encoding");
  }
  EncodeOptions eo = options;
  eo.dtype = a.dtype;  // the sparse payload depends on the element type: always the array's
  if (chunk < a.ChunkCount()) eo.line_length = CodedLineLength(a.layout, a.Extent(chunk));  // and kCoded on the line
  EncodedChunk c = EncodeChunk(data, eo);
  return Append(array, chunk, c, sum);
}

Status ContainerWriter::Discard() {
  const std::string p = path();
  Status s = direct_.Close();
  Status c = file_.Close();
  if (s.ok()) s = c;
  if (!p.empty()) {
    if (std::remove(p.c_str()) == 0) {
      RecordIo({IoOp::Kind::kRemove, p, {}, 0, {}});
    } else if (errno != ENOENT && s.ok()) {
      s = IoError(p + ": remove", errno);
    }
  }
  *this = ContainerWriter();
  return s;
}

Status ContainerWriter::CheckResumedChunk(uint32_t array, uint64_t chunk, ByteSpan data) const {
  std::shared_ptr<const ContainerReader> reader;
  {
    std::lock_guard<std::mutex> lock(mu_);
    if (committed_.count(Key(array, chunk)) == 0 || hashed_.count(Key(array, chunk)) != 0) return Status::Ok();
    if (!resumed_reader_) {
      auto r = ContainerReader::Open(path());
      if (!r.ok()) return r.status().WithContext("reading back a chunk an earlier run committed");
      resumed_reader_ = std::make_shared<const ContainerReader>(std::move(r).value());
    }
    reader = resumed_reader_;
  }
  auto c = reader->ReadChunk(array, chunk);
  if (!c.ok()) return c.status().WithContext("reading back a chunk an earlier run committed");
  const ArraySpec& a = metadata_.arrays[array];
  const ChunkExtent e = a.Extent(chunk);
  const ByteSpan had = c->bytes();
  if (had.size() == data.size() && std::memcmp(had.data(), data.data(), data.size()) == 0) return Status::Ok();
  const uint64_t item = DTypeSize(a.dtype);
  uint64_t i = 0;
  const uint64_t n = std::min(had.size(), data.size()) / item;
  while (i < n && std::memcmp(had.data() + i * item, data.data() + i * item, item) == 0) ++i;
  // Element i of the chunk in its layout: rows layout row-major, cols layout column-major.
  const bool rows_layout = a.layout == Layout::kRows;
  const uint64_t width = rows_layout ? e.cols : e.rows;
  const uint64_t row = e.row0 + (rows_layout ? i / std::max<uint64_t>(1, width) : i % std::max<uint64_t>(1, width));
  const uint64_t col = e.col0 + (rows_layout ? i % std::max<uint64_t>(1, width) : i / std::max<uint64_t>(1, width));
  std::string values;
  if (a.dtype == DType::kF32 && i < n) {
    float x, y;
    std::memcpy(&x, had.data() + i * item, 4);
    std::memcpy(&y, data.data() + i * item, 4);
    char buf[96];
    std::snprintf(buf, sizeof(buf), ": committed %.9g, this run's input %.9g", static_cast<double>(x),
                  static_cast<double>(y));
    values = buf;
  }
  return FailedPrecondition(path() + ": array \"" + a.name + "\" chunk " + std::to_string(chunk) + " (rows " +
                            std::to_string(e.row0) + "-" + std::to_string(e.row0 + e.rows - 1) + ", columns " +
                            std::to_string(e.col0) + "-" + std::to_string(e.col0 + e.cols - 1) +
                            "), committed by an earlier run, differs from this run's input at row " +
                            std::to_string(row) + ", column " + std::to_string(col) + values +
                            ": the input changed since that run, so the file cannot be resumed; remove it, or rerun "
                            "with --overwrite to start over");
}

Status ContainerWriter::HashResumedChunks() {
  if (hashed_.size() == committed_.size()) return Status::Ok();
  LTB_ASSIGN_OR_RETURN(ContainerReader reader, ContainerReader::Open(path()));
  for (const IndexEntry& e : frames_) {
    const uint32_t array = e.header.array;
    const uint64_t chunk = e.header.chunk_index;
    if (hashed_.count(Key(array, chunk)) != 0) continue;
    auto c = reader.ReadChunk(array, chunk);
    if (!c.ok()) return c.status().WithContext("hashing a chunk committed before this writer resumed");
    hash_sums_[array] += ChunkHashSum(metadata_.arrays[array], c->extent(), c->bytes());
    hashed_.insert(Key(array, chunk));
  }
  return Status::Ok();
}

Status ContainerWriter::Finish() {
  std::lock_guard<std::mutex> lock(mu_);
  if (sealed_) return Status::Ok();
  uint64_t missing = 0;
  std::string first;
  for (uint32_t a = 0; a < metadata_.arrays.size(); ++a) {
    for (uint64_t i = 0; i < metadata_.arrays[a].ChunkCount(); ++i) {
      if (committed_.count(Key(a, i)) != 0 || !metadata_.Owns(a, i)) continue;
      if (missing++ == 0) first = "array \"" + metadata_.arrays[a].name + "\" chunk " + std::to_string(i);
    }
  }
  if (missing > 0) {
    return FailedPrecondition(path() + ": cannot seal: " + std::to_string(missing) +
                              " chunks missing (first: " + first + ")");
  }
  LTB_RETURN_IF_ERROR(HashResumedChunks());
  std::vector<std::byte> record = EncodeContentHashRecord(hash_sums_);
  FrameHeader rh;
  rh.type = static_cast<uint16_t>(FrameType::kContentHash);
  rh.flags = kFrameFlagOptional;
  rh.payload_length = record.size();
  rh.decoded_length = record.size();
  rh.payload_checksum = Checksum(record);
  const uint64_t record_offset = end_;
  std::vector<std::byte> index = EncodeIndex(frames_);
  FrameHeader h;
  h.type = static_cast<uint16_t>(FrameType::kIndex);
  h.payload_length = index.size();
  h.decoded_length = index.size();
  h.payload_checksum = Checksum(index);
  uint64_t index_offset = record_offset + rh.FrameSize();  // == + ContentHashFrameSize(arrays)
  uint64_t trailer_offset = index_offset + h.FrameSize();
  Trailer t;
  t.index_offset = index_offset;
  t.file_length = trailer_offset + kTrailerSize;
  // The index frame's region is zero-extended first and its header written before its
  // payload, so a writer killed at any point of sealing leaves either zeros (an
  // uncommitted tail) or an index frame whose declared length covers the partial payload.
  // The payload holds copies of chunk frame headers; written before its own header, those
  // copies would read as frames to a scanner.
  // The content-hash frame goes first, payload before header like a chunk; a writer
  // killed after it leaves an optional frame that resuming cuts off (see Resume).
  LTB_RETURN_IF_ERROR(CountMutation());
  LTB_RETURN_IF_ERROR(file_.Truncate(trailer_offset));
  LTB_RETURN_IF_ERROR(CountMutation());
  LTB_RETURN_IF_ERROR(file_.WriteAt(record_offset + kFrameHeaderSize, record));
  LTB_RETURN_IF_ERROR(CountMutation());
  LTB_RETURN_IF_ERROR(file_.WriteAt(record_offset, EncodeFrameHeader(rh)));
  LTB_RETURN_IF_ERROR(CountMutation());
  LTB_RETURN_IF_ERROR(file_.WriteAt(index_offset, EncodeFrameHeader(h)));
  LTB_RETURN_IF_ERROR(CountMutation());
  LTB_RETURN_IF_ERROR(file_.WriteAt(index_offset + kFrameHeaderSize, index));
  LTB_RETURN_IF_ERROR(CountMutation());
  LTB_RETURN_IF_ERROR(file_.WriteAt(trailer_offset, EncodeTrailer(t)));  // the trailer seals
  LTB_RETURN_IF_ERROR(CountMutation());
  if (!BarrierSkipped(kBarrierSealSync)) LTB_RETURN_IF_ERROR(file_.DataSync());
  end_ = t.file_length;
  sealed_ = true;
  return Status::Ok();
}

}  // namespace ltb::io
