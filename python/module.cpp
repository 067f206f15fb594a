// The `_ltbake` extension behind `import ltbake` (docs/PYTHON.md): thin bindings over the
// same libraries the CLI uses (format/, stages/), so there is one implementation of the
// format. The Python package (python/ltbake/__init__.py) builds the user-facing API on it.
//
// Arrays: a raw chunk comes back as a read-only NumPy view on the container's memory map
// (no copy; the view keeps the mapping alive); other encodings are decoded into a buffer
// the array owns. Every call that reads, decodes, verifies or relights releases the GIL.
// Errors: a failed Status becomes ltbake.FormatError, ltbake.IntegrityError or an OSError
// carrying the Status message (file, chunk, value).
#include <pybind11/numpy.h>
#include <pybind11/pybind11.h>
#include <pybind11/stl.h>
#include <sys/mman.h>
#include <unistd.h>

#include <algorithm>
#include <atomic>
#include <cstring>
#include <memory>
#include <mutex>
#include <optional>
#include <string>
#include <thread>
#include <unordered_map>
#include <unordered_set>
#include <vector>

#include "format/chunk_codec.h"
#include "format/content_hash.h"
#include "format/io/container_reader.h"
#include "format/io/container_writer.h"
#include "format/io/mapped_region.h"
#include "format/io/verifier.h"
#include "format/json_text.h"
#include "format/layout.h"
#include "format/version.h"
#include "stages/common/basis.h"
#include "stages/convert/convert.h"
#include "stages/images/envmap.h"
#include "stages/inspect/inspect.h"
#include "stages/relight/run_relight.h"

namespace py = pybind11;

namespace ltb::python {
namespace {

// The exception classes, created when the module loads.
PyObject* g_error = nullptr;            // ltbake.Error
PyObject* g_format_error = nullptr;     // ltbake.FormatError (also a ValueError)
PyObject* g_integrity_error = nullptr;  // ltbake.IntegrityError

// A failed Status on its way to Python; `missing_is_damage`: kNotFound names a chunk that
// was never committed (an incomplete file), not a path.
struct StatusError {
  Status status;
  bool missing_is_damage = false;
};

[[noreturn]] void Throw(const Status& s, bool missing_is_damage = false) { throw StatusError{s, missing_is_damage}; }

template <typename T>
T Take(Result<T>&& r, bool missing_is_damage = false) {
  if (!r.ok()) Throw(r.status(), missing_is_damage);
  return std::move(r).value();
}

// Runs f (returning a Result) without the GIL; its value, or its Status raised.
template <typename F>
auto WithoutGil(F&& f, bool missing_is_damage = false) {
  std::optional<decltype(f())> r;
  {
    py::gil_scoped_release nogil;
    r.emplace(f());
  }
  return Take(std::move(*r), missing_is_damage);
}

// Runs f (returning a Status) without the GIL; raises a failure.
template <typename F>
void CheckWithoutGil(F&& f, bool missing_is_damage = false) {
  Status s;
  {
    py::gil_scoped_release nogil;
    s = f();
  }
  if (!s.ok()) Throw(s, missing_is_damage);
}

void Translate(const StatusError& e) {
  const std::string& m = e.status.message();
  switch (e.status.code()) {
    case StatusCode::kDataLoss:
      PyErr_SetString(g_integrity_error, m.c_str());
      return;
    case StatusCode::kNotFound:
      PyErr_SetString(e.missing_is_damage ? g_integrity_error : PyExc_FileNotFoundError, m.c_str());
      return;
    case StatusCode::kIo:
      PyErr_SetString(PyExc_OSError, m.c_str());
      return;
    case StatusCode::kCancelled:
      PyErr_SetString(PyExc_KeyboardInterrupt, m.c_str());
      return;
    case StatusCode::kInternal:
      PyErr_SetString(g_error, m.c_str());
      return;
    default:  // invalid argument, failed precondition, unimplemented (a newer format)
      PyErr_SetString(g_format_error, m.c_str());
      return;
  }
}

// The CLI's rule for --jobs (cli/common.cpp): 1..1024 worker threads. A bad value raises
// ValueError naming it, instead of reaching the thread pool (jobs=100000 ended the interpreter
// with std::terminate when the threads could not be created).
constexpr int kMaxJobs = 1024;
void CheckJobs(int jobs) {
  if (jobs < 1 || jobs > kMaxJobs) {
    throw py::value_error("jobs=" + std::to_string(jobs) + ": expected 1.." + std::to_string(kMaxJobs) +
                          " worker threads (as ltbake --jobs)");
  }
}

void CheckMemLimit(uint64_t mem_limit) {
  if (mem_limit == 0) throw py::value_error("mem_limit=0: give a memory budget in bytes, e.g. 1 << 30");
}

py::dtype DTypeOf(format::DType t) {
  switch (t) {
    case format::DType::kF32:
      return py::dtype::of<float>();
    case format::DType::kF64:
      return py::dtype::of<double>();
    case format::DType::kU8:
      return py::dtype::of<uint8_t>();
    case format::DType::kI32:
      return py::dtype::of<int32_t>();
    case format::DType::kU32:
      return py::dtype::of<uint32_t>();
    case format::DType::kU64:
      return py::dtype::of<uint64_t>();
  }
  return py::dtype::of<float>();
}

// A read-only array over memory `owner` keeps alive (a capsule is the array's base).
template <typename Owner>
py::array ArrayOver(std::unique_ptr<Owner> owner, const void* data, py::dtype dtype, std::vector<py::ssize_t> shape) {
  py::capsule base(owner.get(), [](void* p) { delete static_cast<Owner*>(p); });
  owner.release();
  py::array a(dtype, shape, {}, data, base);
  py::detail::array_proxy(a.ptr())->flags &= ~py::detail::npy_api::NPY_ARRAY_WRITEABLE_;
  return a;
}

// Starts the reads of the pages of [p, p + n) (MADV_WILLNEED) without waiting: a read
// that then touches them waits for the disk once, for all of them, instead of page fault
// by page fault (a cold 98 KB row: 10 ms through faults); and a gather of many small
// pieces of a cold file has them all in flight at once.
void Prefetch(const std::byte* p, uint64_t n) {
  static const uintptr_t page = static_cast<uintptr_t>(::sysconf(_SC_PAGESIZE));
  if (n == 0) return;
  const uintptr_t b = reinterpret_cast<uintptr_t>(p) & ~(page - 1), e = reinterpret_cast<uintptr_t>(p) + n;
  (void)::madvise(reinterpret_cast<void*>(b), e - b, MADV_WILLNEED);
}

// One open container or manifest. Raw chunks are served from one read-only mapping of
// each file, made on first use (as np.load(mmap_mode="r") maps a .npy): a read costs no
// system call. Chunks are checksum-verified the first time a read touches them (when
// `checksums`), never again.
class Reader {
 public:
  Reader(const std::string& path, bool checksums) : checksums_(checksums) {
    reader_ = std::make_shared<io::ContainerReader>(WithoutGil([&] { return io::ContainerReader::Open(path); }));
  }

  const io::ContainerReader& reader() const { return *reader_; }

  // The chunk in its stored layout: rows layout (rows of the chunk, cols), cols layout
  // (cols of the chunk, rows). Returns (array, zero_copy).
  // With a region hint (r0 < r1), the pages of that part of a raw chunk are prefetched: the
  // caller is about to read them through the view.
  py::tuple ReadChunk(uint32_t array, uint64_t chunk, uint64_t r0, uint64_t r1, uint64_t c0, uint64_t c1) {
    const format::ArraySpec& spec = CheckArray(array);
    if (chunk >= spec.ChunkCount()) {
      throw py::index_error("chunk " + std::to_string(chunk) + " of array \"" + spec.name + "\" is out of range (" +
                            std::to_string(spec.ChunkCount()) + " chunks)");
    }
    const bool rows = spec.layout == format::Layout::kRows;
    const format::ChunkExtent e = spec.Extent(chunk);
    std::vector<py::ssize_t> shape = {static_cast<py::ssize_t>(rows ? e.rows : e.cols),
                                      static_cast<py::ssize_t>(rows ? e.cols : e.rows)};
    Raw raw;
    auto decoded = std::make_unique<io::Chunk>();
    CheckWithoutGil([&] { return Load(array, chunk, &raw, decoded.get()); }, true);
    if (raw.data != nullptr) {
      if (r0 < r1 && c0 < c1) PrefetchRegion(spec, chunk, raw.data, r0, r1, c0, c1, !FirstTouch(array, chunk));
      auto owner = std::make_unique<std::shared_ptr<const io::MappedRegion>>(std::move(raw.map));
      return py::make_tuple(ArrayOver(std::move(owner), raw.data, DTypeOf(spec.dtype), shape), true);
    }
    const void* data = decoded->bytes().data();
    return py::make_tuple(ArrayOver(std::move(decoded), data, DTypeOf(spec.dtype), shape), false);
  }

  // Rows [r0, r1) × columns [c0, c1) of an array, gathered from every chunk they touch
  // into a new C-order array, `jobs` chunks at a time. The pieces a raw chunk contributes
  // are prefetched before they are copied.
  py::array ReadRegion(uint32_t array, uint64_t r0, uint64_t r1, uint64_t c0, uint64_t c1, int jobs) {
    CheckJobs(jobs);
    const format::ArraySpec& spec = CheckArray(array);
    if (r0 > r1 || r1 > spec.rows || c0 > c1 || c1 > spec.cols) throw py::index_error("region out of range");
    const uint64_t nr = r1 - r0, nc = c1 - c0, item = format::DTypeSize(spec.dtype);
    py::array out(DTypeOf(spec.dtype),
                  std::vector<py::ssize_t>{static_cast<py::ssize_t>(nr), static_cast<py::ssize_t>(nc)});
    if (nr == 0 || nc == 0) return out;
    std::byte* dst = static_cast<std::byte*>(out.mutable_data());
    const bool rows = spec.layout == format::Layout::kRows;
    const uint64_t lo = rows ? r0 : c0, hi = rows ? r1 : c1;
    const uint64_t k0 = lo / spec.block, k1 = (hi - 1) / spec.block + 1;
    // The error raised is the first failing chunk's, whichever thread met a failure first:
    // chunks are claimed in order, so every chunk below a failing one is read to the end.
    Status failed;
    uint64_t failed_chunk = k1;
    {
      py::gil_scoped_release nogil;
      std::atomic<uint64_t> next{k0};
      std::mutex mu;
      auto work = [&] {
        for (uint64_t k = next++; k < k1; k = next++) {
          Status s = CopyFromChunk(array, spec, k, r0, r1, c0, c1, item, dst);
          if (!s.ok()) {
            std::lock_guard<std::mutex> lock(mu);
            if (k < failed_chunk) {
              failed = s;
              failed_chunk = k;
            }
            next = k1;
          }
        }
      };
      const int n = static_cast<int>(std::clamp<uint64_t>(static_cast<uint64_t>(std::max(1, jobs)), 1, k1 - k0));
      std::vector<std::thread> threads;
      for (int t = 1; t < n; ++t) threads.emplace_back(work);
      work();
      for (auto& t : threads) t.join();
    }
    if (!failed.ok()) Throw(failed, true);
    return out;
  }

  bool checksums() const { return checksums_; }

 private:
  // A raw chunk's payload inside its file's mapping (data == nullptr for other encodings).
  struct Raw {
    std::shared_ptr<const io::MappedRegion> map;
    const std::byte* data = nullptr;
  };

  const format::ArraySpec& CheckArray(uint32_t array) const {
    const auto& arrays = reader_->metadata().arrays;
    if (array >= arrays.size()) throw py::index_error("array " + std::to_string(array) + " out of range");
    return arrays[array];
  }

  // A raw chunk: its bytes in the mapping of the file holding it (verified on first use);
  // any other encoding: decoded into `decoded`.
  Status Load(uint32_t array, uint64_t chunk, Raw* raw, io::Chunk* decoded) {
    const format::IndexEntry* e = reader_->Find(array, chunk);
    if (e == nullptr || e->header.encoding != static_cast<uint16_t>(format::Encoding::kRaw)) {
      io::ReadOptions o;
      o.sequential = false;
      auto c = reader_->ReadChunk(array, chunk, o);  // names the missing chunk; decodes verify anyway
      if (!c.ok()) return c.status();
      *decoded = std::move(c).value();
      return Status::Ok();
    }
    if (checksums_ && !Verified(array, chunk)) {
      io::ReadOptions o;
      o.sequential = false;
      auto c = reader_->ReadChunk(array, chunk, o);  // maps and checks the payload
      if (!c.ok()) return c.status();
      MarkVerified(array, chunk);
    }
    const io::ContainerReader& holder = reader_->Holder(array, chunk);
    std::shared_ptr<const io::MappedRegion> map;
    {
      std::lock_guard<std::mutex> lock(mu_);
      auto& slot = maps_[&holder];
      if (slot == nullptr) {
        // The reader checked every frame against the size it found, so the mapping covers it.
        auto m = io::MappedRegion::Map(holder.file().fd(), 0, holder.file_size(), false);
        if (!m.ok()) return m.status().WithContext(holder.path());
        slot = std::make_shared<const io::MappedRegion>(std::move(m).value());
      }
      map = slot;
    }
    raw->data = map->bytes().data() + e->frame_offset + format::kFrameHeaderSize;
    raw->map = std::move(map);
    return Status::Ok();
  }

  bool Verified(uint32_t array, uint64_t chunk) {
    std::lock_guard<std::mutex> lock(mu_);
    return verified_.count((uint64_t{array} << 40) | chunk) != 0;
  }
  void MarkVerified(uint32_t array, uint64_t chunk) {
    std::lock_guard<std::mutex> lock(mu_);
    verified_.insert((uint64_t{array} << 40) | chunk);
  }

  // Whether this is the first gather from chunk k (later ones find its pages cached).
  bool FirstTouch(uint32_t array, uint64_t chunk) {
    std::lock_guard<std::mutex> lock(mu_);
    return touched_.insert((uint64_t{array} << 40) | chunk).second;
  }

  // Prefetches the pieces of rows [r0, r1) × columns [c0, c1) in raw chunk k at `src`: one
  // range when they are contiguous in the chunk, else (unless only_contiguous) each piece.
  static void PrefetchRegion(const format::ArraySpec& spec, uint64_t k, const std::byte* src, uint64_t r0, uint64_t r1,
                             uint64_t c0, uint64_t c1, bool only_contiguous) {
    const format::ChunkExtent e = spec.Extent(k);
    const uint64_t item = format::DTypeSize(spec.dtype);
    const bool rows = spec.layout == format::Layout::kRows;
    // Lines (rows of a rows chunk, columns of a cols chunk) a..b, the piece [p0, p1) of each.
    const uint64_t line = rows ? e.cols : e.rows;
    const uint64_t a = rows ? std::max(r0, e.row0) - e.row0 : std::max(c0, e.col0) - e.col0;
    const uint64_t b = rows ? std::min(r1, e.row0 + e.rows) - e.row0 : std::min(c1, e.col0 + e.cols) - e.col0;
    const uint64_t p0 = rows ? c0 : r0, p1 = rows ? c1 : r1;
    if (a >= b || p0 >= p1) return;
    if (p1 - p0 == line) {
      Prefetch(src + a * line * item, (b - a) * line * item);
    } else if (b - a == 1) {
      Prefetch(src + (a * line + p0) * item, (p1 - p0) * item);
    } else if (!only_contiguous) {
      for (uint64_t l = a; l < b; ++l) Prefetch(src + (l * line + p0) * item, (p1 - p0) * item);
    }
  }

  Status CopyFromChunk(uint32_t array, const format::ArraySpec& spec, uint64_t k, uint64_t r0, uint64_t r1, uint64_t c0,
                       uint64_t c1, uint64_t item, std::byte* dst) {
    Raw raw;
    io::Chunk decoded;
    LTB_RETURN_IF_ERROR(Load(array, k, &raw, &decoded));
    const format::ChunkExtent e = spec.Extent(k);
    const std::byte* src = raw.data != nullptr ? raw.data : decoded.bytes().data();
    const uint64_t nc = c1 - c0;
    if (raw.data != nullptr && FirstTouch(array, k)) PrefetchRegion(spec, k, raw.data, r0, r1, c0, c1, false);
    if (spec.layout == format::Layout::kRows) {
      const uint64_t a = std::max(r0, e.row0), b = std::min(r1, e.row0 + e.rows);
      auto at = [&](uint64_t r) { return src + ((r - e.row0) * e.cols + c0) * item; };
      for (uint64_t r = a; r < b; ++r) std::memcpy(dst + (r - r0) * nc * item, at(r), nc * item);
    } else {
      const uint64_t a = std::max(c0, e.col0), b = std::min(c1, e.col0 + e.cols), nr = r1 - r0;
      auto at = [&](uint64_t col) { return src + ((col - e.col0) * e.rows + r0) * item; };
      for (uint64_t col = a; col < b; ++col) {
        const std::byte* s = at(col);
        std::byte* d = dst + (col - c0) * item;
        if (item == 4) {
          for (uint64_t r = 0; r < nr; ++r) std::memcpy(d + r * nc * 4, s + r * 4, 4);
        } else {
          for (uint64_t r = 0; r < nr; ++r) std::memcpy(d + r * nc * item, s + r * item, item);
        }
      }
    }
    return Status::Ok();
  }

  std::shared_ptr<io::ContainerReader> reader_;
  bool checksums_;
  std::mutex mu_;
  std::unordered_set<uint64_t> verified_, touched_;
  std::unordered_map<const io::ContainerReader*, std::shared_ptr<const io::MappedRegion>> maps_;
};

// Appends chunks to a new (or resumed) container; Python slices the data into chunks.
class Writer {
 public:
  Writer(const std::string& path, const std::string& metadata_json, bool overwrite) {
    auto parsed = ParseJson(metadata_json);
    if (!parsed.ok()) Throw(InvalidArgument(path + ": metadata is not valid JSON: " + parsed.status().message()));
    nlohmann::json meta = std::move(*parsed);
    io::WriterOptions wo;
    wo.overwrite_mismatch = overwrite;
    writer_ = WithoutGil([&] { return io::ContainerWriter::Open(path, meta, wo); });
  }

  bool Has(uint32_t array, uint64_t chunk) const { return writer_.Has(array, chunk); }

  // `data`: the chunk's values in the array's layout and dtype, C-contiguous.
  void Put(uint32_t array, uint64_t chunk, py::array data, bool zstd) {
    const auto& arrays = writer_.metadata().arrays;
    if (array >= arrays.size()) throw py::index_error("array out of range");
    const format::ArraySpec& spec = arrays[array];
    if (chunk >= spec.ChunkCount()) throw py::index_error("chunk out of range");
    if (!(data.flags() & py::array::c_style) || !data.dtype().is(DTypeOf(spec.dtype))) {
      Throw(InvalidArgument("chunk data must be C-contiguous " + std::string(format::DTypeName(spec.dtype))));
    }
    const uint64_t bytes = static_cast<uint64_t>(data.nbytes());
    if (bytes != spec.ChunkBytes(chunk)) {
      Throw(InvalidArgument("chunk " + std::to_string(chunk) + " of \"" + spec.name + "\" holds " +
                            std::to_string(spec.ChunkBytes(chunk)) + " bytes, got " + std::to_string(bytes)));
    }
    format::EncodeOptions eo;
    eo.zstd = zstd;
    const format::ByteSpan span(static_cast<const std::byte*>(data.data()), bytes);
    CheckWithoutGil([&] { return writer_.Put(array, chunk, span, eo); });
  }

  // Raises FormatError unless a chunk an earlier (interrupted) write committed holds `data`
  // (the input changed since); nothing to check for a chunk this writer put or lacks.
  void Check(uint32_t array, uint64_t chunk, py::array data) {
    const auto& arrays = writer_.metadata().arrays;
    if (array >= arrays.size()) throw py::index_error("array out of range");
    if (chunk >= arrays[array].ChunkCount()) throw py::index_error("chunk out of range");
    if (!(data.flags() & py::array::c_style) || !data.dtype().is(DTypeOf(arrays[array].dtype))) {
      Throw(InvalidArgument("chunk data must be C-contiguous " + std::string(format::DTypeName(arrays[array].dtype))));
    }
    const format::ByteSpan span(static_cast<const std::byte*>(data.data()), static_cast<uint64_t>(data.nbytes()));
    CheckWithoutGil([&] { return writer_.CheckResumedChunk(array, chunk, span); });
  }

  void Finish() {
    CheckWithoutGil([&] { return writer_.Finish(); });
  }

  // Closes and removes the file (a restart under overwrite=True).
  void Discard() {
    CheckWithoutGil([&] { return writer_.Discard(); });
  }

 private:
  io::ContainerWriter writer_;
};

py::dict VerifyReport(const std::string& path, int jobs) {
  CheckJobs(jobs);
  io::VerifyReport r;
  {
    py::gil_scoped_release nogil;
    r = io::VerifyContainer(path, jobs);
  }
  py::dict d;
  d["file"] = r.path;
  d["readable"] = r.readable;
  d["sealed"] = r.sealed;
  d["complete"] = r.complete;
  d["chunks_expected"] = r.chunks_expected;
  d["chunks_ok"] = r.chunks_ok;
  d["uncommitted_tail_bytes"] = r.uncommitted_tail_bytes;
  d["content_hash"] = r.content_hash;
  d["recorded_content_hash"] = r.recorded_content_hash;
  d["problems"] = r.problems;
  d["notes"] = r.notes;
  return d;
}

std::string Inspect(const std::string& path, bool content, bool chunk_list, int jobs) {
  CheckJobs(jobs);
  stages::InspectOptions o;
  o.content = content;
  o.chunk_list = chunk_list;
  o.jobs = jobs;
  return JsonText(WithoutGil([&] { return stages::InspectContainer(path, o, Progress{}); }));
}

py::array FloatArray(std::vector<float> v, std::vector<py::ssize_t> shape) {
  auto owner = std::make_unique<std::vector<float>>(std::move(v));
  const void* data = owner->data();
  return ArrayOver(std::move(owner), data, py::dtype::of<float>(), std::move(shape));
}

py::tuple Relight(const std::string& matrix, const std::string& env, uint64_t terms, const std::string& weighting,
                  double rotate_deg, bool clamp_env, bool keep_negative, int jobs, uint64_t mem_limit,
                  const std::optional<py::array_t<float, py::array::c_style | py::array::forcecast>>& cubemap) {
  CheckJobs(jobs);
  CheckMemLimit(mem_limit);
  stages::RelightOptions o;
  o.matrix = matrix;
  o.env = env;
  o.terms = terms == 0 ? stages::RelightOptions::kAllTerms : terms;
  o.weighting = Take(stages::ParseWeighting(weighting));
  o.rotate_deg = rotate_deg;
  o.clamp_env = clamp_env;
  o.keep_negative = keep_negative;
  o.jobs = jobs;
  o.mem_limit = mem_limit;
  o.return_image = true;
  if (cubemap) {  // a 6R² × 3 cubemap in memory instead of a file
    if (cubemap->ndim() != 2 || cubemap->shape(1) != 3) {
      throw py::value_error(env + ": an environment array must be a 6R^2 x 3 cubemap (rows of RGB)");
    }
    o.env_cubemap.assign(cubemap->data(), cubemap->data() + cubemap->size());
  }
  stages::RelightResult res = WithoutGil([&] { return stages::RunRelight(o, Progress{}); });
  const py::ssize_t rows = static_cast<py::ssize_t>(res.image.size() / 3);
  return py::make_tuple(FloatArray(std::move(res.image), {rows, 3}), JsonText(res.report));
}

py::array Envmap(const std::string& path, uint64_t cube_res, bool clamp, uint64_t max_bytes) {
  stages::EnvLoadOptions o;
  o.clamp = clamp;
  o.max_bytes = max_bytes;
  std::vector<float> cube = WithoutGil([&] { return stages::EnvToCubemap(path, cube_res, o); });
  const py::ssize_t texels = static_cast<py::ssize_t>(cube.size() / 3);
  return FloatArray(std::move(cube), {texels, 3});
}

void Convert(const std::string& input, const std::string& output, bool pixel_basis, int jobs, uint64_t mem_limit) {
  CheckJobs(jobs);
  CheckMemLimit(mem_limit);
  stages::ConvertOptions o;
  o.input = input;
  o.output = output;
  o.pixel_basis = pixel_basis;
  o.jobs = jobs;
  o.mem_limit = mem_limit;
  (void)WithoutGil([&] { return stages::RunConvert(o, Progress{}); });
}

PyObject* NewException(py::module_& m, const char* name, PyObject* bases, const char* doc) {
  PyObject* e = PyErr_NewExceptionWithDoc((std::string("ltbake.") + name).c_str(), doc, bases, nullptr);
  if (e == nullptr) throw py::error_already_set();
  m.add_object(name, py::handle(e));
  return e;
}

}  // namespace
}  // namespace ltb::python

using namespace ltb;          // NOLINT
using namespace ltb::python;  // NOLINT

PYBIND11_MODULE(_ltbake, m) {
  m.doc() = "ltbake's container and relighting libraries (use the `ltbake` package, docs/PYTHON.md)";
  g_error = NewException(m, "Error", PyExc_Exception, "Base of ltbake's errors.");
  {
    py::tuple bases = py::make_tuple(py::handle(g_error), py::handle(PyExc_ValueError));
    g_format_error = NewException(m, "FormatError", bases.ptr(),
                                  "A file that is not what it claims, a newer format, or a bad argument.");
  }
  g_integrity_error = NewException(m, "IntegrityError", g_error,
                                   "Damage: a checksum mismatch, a truncated structure, a missing chunk.");
  py::register_exception_translator([](std::exception_ptr p) {
    try {
      if (p) std::rethrow_exception(p);
    } catch (const StatusError& e) {
      Translate(e);
    }
  });
  m.attr("tool_version") = std::string(kToolVersion);

  py::class_<Reader>(m, "Reader")
      .def(py::init<const std::string&, bool>(), py::arg("path"), py::arg("checksums") = true)
      .def_property_readonly("path", [](const Reader& r) { return r.reader().path(); })
      .def_property_readonly("metadata_json", [](const Reader& r) { return JsonText(r.reader().metadata().json); })
      .def_property_readonly("file_size", [](const Reader& r) { return r.reader().file_size(); })
      .def_property_readonly("sealed", [](const Reader& r) { return r.reader().sealed(); })
      .def_property_readonly("complete", [](const Reader& r) { return r.reader().complete(); })
      .def_property_readonly("problems", [](const Reader& r) { return r.reader().problems(); })
      .def_property_readonly("checksums", &Reader::checksums)
      .def_property_readonly("format_version",
                             [](const Reader& r) {
                               return std::to_string(r.reader().header().major) + "." +
                                      std::to_string(r.reader().header().minor);
                             })
      .def_property_readonly("shards",
                             [](const Reader& r) {
                               std::vector<std::string> s;
                               for (const auto& p : r.reader().shards()) s.push_back(p->path());
                               return s;
                             })
      .def("committed", [](const Reader& r, uint32_t a) { return r.reader().committed(a); })
      .def("recorded_content_hash", [](const Reader& r, uint32_t a) { return r.reader().RecordedContentHash(a); })
      .def("chunk_frames",
           [](const Reader& r) {
             py::list out;
             for (const auto& e : r.reader().chunk_frames()) {
               out.append(py::make_tuple(e.header.array, e.header.chunk_index,
                                         format::EncodingName(static_cast<format::Encoding>(e.header.encoding)),
                                         e.header.payload_length, e.header.decoded_length, e.frame_offset,
                                         r.reader().Holder(e.header.array, e.header.chunk_index).path()));
             }
             return out;
           })
      .def("read_chunk", &Reader::ReadChunk, py::arg("array"), py::arg("chunk"), py::arg("r0") = 0, py::arg("r1") = 0,
           py::arg("c0") = 0, py::arg("c1") = 0)
      .def("read_region", &Reader::ReadRegion, py::arg("array"), py::arg("r0"), py::arg("r1"), py::arg("c0"),
           py::arg("c1"), py::arg("jobs") = 2);

  py::class_<Writer>(m, "Writer")
      .def(py::init<const std::string&, const std::string&, bool>(), py::arg("path"), py::arg("metadata_json"),
           py::arg("overwrite") = false)
      .def("has", &Writer::Has)
      .def("put", &Writer::Put, py::arg("array"), py::arg("chunk"), py::arg("data"), py::arg("zstd") = false)
      .def("check", &Writer::Check, py::arg("array"), py::arg("chunk"), py::arg("data"))
      .def("discard", &Writer::Discard)
      .def("finish", &Writer::Finish);

  m.def("block_for_target_bytes", [](uint64_t rows, uint64_t cols, const std::string& layout, uint64_t target) {
    return format::BlockForTargetBytes(rows, cols, format::DType::kF32,
                                       layout == "cols" ? format::Layout::kCols : format::Layout::kRows, target);
  });
  // The "basis" entry of an axis, as the stages write it: "generic", "cubemap" (a = R),
  // "image" (a = W, b = H).
  m.def("axis_basis_json", [](const std::string& kind, uint64_t a, uint64_t b) {
    if (kind == "cubemap") return JsonText(stages::PixelCubemapCols(a));
    if (kind == "image") return JsonText(stages::ImageRows(a, b));
    return JsonText(stages::GenericAxis());
  });
  m.def("verify_report", &VerifyReport, py::arg("path"), py::arg("jobs") = 2);
  m.def("inspect_json", &Inspect, py::arg("path"), py::arg("content") = true, py::arg("chunk_list") = false,
        py::arg("jobs") = 2);
  m.def("relight", &Relight, py::arg("matrix"), py::arg("env"), py::arg("terms"), py::arg("weighting"),
        py::arg("rotate_deg"), py::arg("clamp_env"), py::arg("keep_negative"), py::arg("jobs"), py::arg("mem_limit"),
        py::arg("cubemap") = py::none());
  m.def("envmap", &Envmap, py::arg("path"), py::arg("cube_res"), py::arg("clamp"), py::arg("max_bytes"));
  m.def("convert", &Convert, py::arg("input"), py::arg("output"), py::arg("pixel_basis"), py::arg("jobs"),
        py::arg("mem_limit"));
}
