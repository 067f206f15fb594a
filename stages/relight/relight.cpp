#include "stages/relight/relight.h"

#include <algorithm>
#include <cmath>
#include <cstdio>
#include <cstring>
#include <limits>
#include <mutex>
#include <numeric>
#include <optional>

#include "format/io/container_reader.h"
#include "format/io/file.h"
#include "format/npy.h"
#include "stages/column_transform/column_codec.h"
#include "stages/common/basis.h"
#include "stages/common/parallel_for.h"

namespace ltb::stages {

using namespace ltb::format;

Result<Weighting> ParseWeighting(const std::string& name) {
  if (name == "area") return Weighting::kArea;
  if (name == "transport") return Weighting::kTransport;
  if (name == "none") return Weighting::kNone;
  return InvalidArgument("--weighting \"" + name + "\": expected area, transport or none");
}

const char* WeightingName(Weighting w) {
  switch (w) {
    case Weighting::kArea:
      return "area";
    case Weighting::kTransport:
      return "transport";
    case Weighting::kNone:
      return "none";
  }
  return "?";
}

namespace {

// Support area, in texels, of the basis function of each column of one face's Mallat
// layout at full depth: the scaling function covers the face; a level-l detail (l = 0
// coarsest) covers (R / 2^l)².
std::vector<float> FaceSupportAreas(uint64_t r, bool wavelet) {
  std::vector<float> a(r * r, 1.0f);
  if (!wavelet) return a;
  for (uint64_t t = 0; t < r; ++t)
    for (uint64_t s = 0; s < r; ++s) {
      uint64_t m = std::max(s, t);
      if (m == 0) {
        a[t * r + s] = static_cast<float>(r * r);
        continue;
      }
      int l = 63 - __builtin_clzll(m);
      double side = static_cast<double>(r) / std::ldexp(1.0, l);
      a[t * r + s] = static_cast<float>(side * side);
    }
  return a;
}

}  // namespace

Result<LightingBasis> LightingBasis::FromMetadata(const Metadata& meta, const std::string& path) {
  auto cube = ReadCubemapCols(meta);
  if (!cube.ok()) return cube.status().WithContext(path);
  if (!cube->has_value()) {
    return FailedPrecondition(path + ": its columns are not declared a cubemap; relight needs the lights of a bake");
  }
  if ((*cube)->basis != "pixel" && (*cube)->basis != "wavelet") {
    return FailedPrecondition(path + ": its columns are in basis \"" + (*cube)->basis +
                              "\" (a visibility or material field of the triple-product path); relight a visibility "
                              "field with --material and --eye (docs/TRIPLE.md)");
  }
  LightingBasis b;
  b.cube_res_ = (*cube)->cube_res;
  b.wavelet_ = (*cube)->basis == "wavelet";
  if (b.wavelet_) {
    LTB_ASSIGN_OR_RETURN(b.filter_, wavelet::ParseFilter((*cube)->filter));
  }
  std::vector<float> face = FaceSupportAreas(b.cube_res_, b.wavelet_);
  const uint64_t n = 6 * b.cube_res_ * b.cube_res_;
  b.area_.resize(n);
  for (uint64_t j = 0; j < n; ++j) b.area_[j] = face[j % (b.cube_res_ * b.cube_res_)];
  return b;
}

void LightingBasis::ToBasis(float* cubemap) const {
  if (!wavelet_) return;
  const uint64_t r = cube_res_;
  std::vector<float> scratch(wavelet::ScratchSize(r, r, 3));
  for (int f = 0; f < 6; ++f) {
    wavelet::Forward2D(filter_, cubemap + f * r * r * 3, r, r, 3, wavelet::MaxDepth(r, r), scratch.data());
  }
}

void LightingBasis::ToPixels(float* cubemap) const {
  if (!wavelet_) return;
  const uint64_t r = cube_res_;
  std::vector<float> scratch(wavelet::ScratchSize(r, r, 3));
  for (int f = 0; f < 6; ++f) {
    wavelet::Inverse2D(filter_, cubemap + f * r * r * 3, r, r, 3, wavelet::MaxDepth(r, r), scratch.data());
  }
}

Status LightingBasis::SelectTerms(const float* lighting, uint64_t terms, Weighting weighting,
                                  const std::vector<double>& column_norms, LightTerms* out) const {
  out->column.clear();
  out->rgb.clear();
  const uint64_t cols = area_.size();
  if (weighting == Weighting::kTransport && column_norms.size() != cols) {
    return FailedPrecondition(
        "--weighting transport needs the norms of the matrix's columns (relight from a "
        "column-block matrix: final.ltm, cols4d.ltm or cols.ltm)");
  }
  std::vector<std::pair<double, uint32_t>> cand;
  cand.reserve(cols);
  for (uint64_t j = 0; j < cols; ++j) {
    double r = lighting[j * 3], g = lighting[j * 3 + 1], b = lighting[j * 3 + 2];
    double m = std::sqrt(r * r + g * g + b * b);
    if (m == 0) continue;
    if (weighting == Weighting::kArea) m *= area_[j];
    if (weighting == Weighting::kTransport) {
      m *= column_norms[j];
      if (m == 0) continue;  // a light that reaches nothing
    }
    cand.push_back({m, static_cast<uint32_t>(j)});
  }
  auto better = [](const std::pair<double, uint32_t>& x, const std::pair<double, uint32_t>& y) {
    return x.first > y.first || (x.first == y.first && x.second < y.second);
  };
  if (cand.size() > terms) {
    std::nth_element(cand.begin(), cand.begin() + static_cast<std::ptrdiff_t>(terms), cand.end(), better);
    cand.resize(terms);
  }
  std::sort(cand.begin(), cand.end(), [](const auto& x, const auto& y) { return x.second < y.second; });
  for (const auto& c : cand) {
    out->column.push_back(c.second);
    for (int k = 0; k < 3; ++k) out->rgb.push_back(lighting[c.second * 3 + k]);
  }
  return Status::Ok();
}

Status Relighter::AppendChunk(const std::string& path, const ColumnCodec* codec, uint64_t mem_limit,
                              const LoadedChunk& d) {
  const SparseChunk& sc = d.sc;
  const ChunkExtent& e = sc.extent;
  const std::vector<uint8_t>& depths = d.depths;
  const std::vector<double>&scales = d.scales, &energy = d.energy;
  const uint64_t pixels = rows_;
  size_t pos = 0;
  for (uint64_t k = 0; k < e.cols; ++k) {
    const uint64_t j = e.col0 + k;
    if (depths[k] > max_depth_) {
      return DataLoss(path + ": column " + std::to_string(j) + " has depth " + std::to_string(depths[k]));
    }
    if (!std::isfinite(scales[k]) || scales[k] < 0) {
      return DataLoss(path + ": column " + std::to_string(j) + " has scale " + std::to_string(scales[k]));
    }
    depth_[j] = depths[k];
    const std::vector<double>* factor = codec && codec->quantization().bits > 0 ? &codec->Factors(depths[k]) : nullptr;
    const double step = factor ? scales[k] / codec->quantization().Levels() : 1.0;
    double e2 = 0;
    while (pos < sc.index.size() && sc.index[pos] < (k + 1) * pixels) {
      uint32_t p = sc.index[pos] - static_cast<uint32_t>(k * pixels);
      float v;
      if (factor) {
        int32_t q;
        std::memcpy(&q, sc.values.data() + pos * 4, 4);
        v = static_cast<float>(static_cast<double>(q) * step / (*factor)[p]);
      } else {
        std::memcpy(&v, sc.values.data() + pos * 4, 4);
      }
      pos_.push_back(p);
      values_.push_back(v);
      e2 += static_cast<double>(v) * v * (synthesis_energy_.empty() ? 1.0 : synthesis_energy_[depths[k]][p]);
      ++pos;
    }
    col_ptr_[j + 1] = values_.size();
    if (values_.size() * 8 > mem_limit) {
      return FailedPrecondition(
          path + ": its nonzeros need more than --mem-limit (" + std::to_string(mem_limit >> 20) +
          " MiB) in memory (8 bytes each; " + std::to_string(values_.size()) + " by column " + std::to_string(j) +
          " of " + std::to_string(cols_) +
          "); raise --mem-limit, compress it further, or relight the row-block matrix (streamed)");
    }
    // ‖T_j‖ in the image: the column's recorded energy (column-transform outputs), else
    // its kept values' energy, each weighted by its basis function's ‖ψ̃‖² (quantize outputs,
    // which carry no column_stats: exact for the orthonormal filters' kept part, up to the
    // cross terms of the biorthogonal basis for LeGall 5/3; plain columns: ‖ψ̃‖ = 1).
    column_norm_[j] = std::sqrt(energy[k] >= 0 ? energy[k] : e2);
  }
  return Status::Ok();
}

Result<Relighter> Relighter::Load(const std::string& path, uint64_t mem_limit, const Progress& progress, int jobs) {
  LTB_ASSIGN_OR_RETURN(io::ContainerReader in, io::ContainerReader::Open(path));
  const Metadata& meta = in.metadata();
  const ArraySpec& a = meta.matrix();
  if (!in.complete()) {
    return FailedPrecondition(path + ": is incomplete; finish the stage that writes it first (rerun it to resume)");
  }
  if (a.layout != Layout::kCols) {
    return FailedPrecondition(path +
                              ": is stored in row blocks; the fast relighter reads column blocks (final.ltm, "
                              "cols4d.ltm or cols.ltm)");
  }
  Relighter r;
  LTB_ASSIGN_OR_RETURN(r.basis_, LightingBasis::FromMetadata(meta, path));
  r.rows_ = a.rows;
  r.cols_ = a.cols;
  std::optional<ColumnCodec> codec;
  if (ColumnCodec::IsColumnTransformed(meta)) {
    LTB_ASSIGN_OR_RETURN(ColumnCodec c, ColumnCodec::FromMetadata(meta, path));
    codec = std::move(c);
    r.width_ = codec->width();
    r.height_ = codec->height();
    r.max_depth_ = codec->max_depth();
    r.col_filter_ = codec->filter();
  } else {
    if (a.dtype != DType::kF32) return FailedPrecondition(path + ": matrix is not f32");
    auto image = ReadImageRows(meta);
    r.width_ = image ? image->width : a.rows;
    r.height_ = image ? image->height : 1;
  }
  r.bands_ = wavelet::BandSizes(r.width_, r.height_, r.max_depth_);
  r.depth_.assign(a.cols, 0);
  r.column_norm_.assign(a.cols, 0.0);
  r.col_ptr_.assign(a.cols + 1, 0);
  int stats_array = -1;
  if (codec) {
    stats_array = meta.FindArray(meta.json["column_transform"].value("stats_array", std::string("column_stats")));
    if (stats_array < 0 && !wavelet::IsOrthonormal(codec->filter())) {
      r.synthesis_energy_ = SynthesisEnergies(codec->filter(), r.width_, r.height_, r.max_depth_);
    }
  }

  // The per-column tables, read once whatever their chunking (a quantize output holds each in
  // one chunk, a column-transform output chunks them like the matrix).
  std::vector<uint8_t> depths;
  std::vector<double> scales, stats;
  if (codec) {
    LTB_ASSIGN_OR_RETURN(depths, ReadLinesAs<uint8_t>(in, codec->depth_array(), 0, a.cols));
    if (codec->scale_array() >= 0) {
      LTB_ASSIGN_OR_RETURN(scales, ReadLinesAs<double>(in, codec->scale_array(), 0, a.cols));
    }
    if (stats_array >= 0) {
      LTB_ASSIGN_OR_RETURN(stats, ReadLinesAs<double>(in, stats_array, 0, a.cols));
    }
  }

  // Chunks are decoded `jobs` at a time in parallel (a sparse-coded chunk decodes at ~7 M
  // nonzeros/s on one core), then appended in order, so the result does not depend on jobs.
  auto decode = [&](uint64_t c, LoadedChunk* d) -> Status {
    LTB_ASSIGN_OR_RETURN(d->sc, in.ReadSparse(0, c));
    const ChunkExtent& e = d->sc.extent;
    d->depths.assign(e.cols, 0);
    d->scales.assign(e.cols, codec && codec->uniform_scale() > 0 ? codec->uniform_scale() : 1.0);
    d->energy.assign(e.cols, -1.0);
    if (!codec) return Status::Ok();
    std::copy_n(depths.begin() + e.col0, e.cols, d->depths.begin());
    if (!scales.empty()) std::copy_n(scales.begin() + e.col0, e.cols, d->scales.begin());
    if (!stats.empty())
      for (uint64_t k = 0; k < e.cols; ++k) d->energy[k] = stats[3 * (e.col0 + k)];
    return Status::Ok();
  };
  const uint64_t window = static_cast<uint64_t>(std::max(1, jobs));
  std::vector<LoadedChunk> batch(window);
  for (uint64_t c0 = 0; c0 < a.ChunkCount(); c0 += window) {
    if (progress.Cancelled()) return Cancelled("interrupted while loading " + path);
    const uint64_t c1 = std::min(a.ChunkCount(), c0 + window);
    std::vector<uint64_t> items(c1 - c0);
    std::iota(items.begin(), items.end(), c0);
    LTB_RETURN_IF_ERROR(ParallelFor(items, jobs, Progress{}, "chunks",
                                    [&](uint64_t c) -> Status { return decode(c, &batch[c - c0]); }));
    for (uint64_t c = c0; c < c1; ++c) {
      LTB_RETURN_IF_ERROR(r.AppendChunk(path, codec ? &*codec : nullptr, mem_limit, batch[c - c0]));
      batch[c - c0] = LoadedChunk{};
      progress.Report(c + 1, a.ChunkCount(), "chunks");
    }
  }
  r.scratch_.resize(wavelet::ScratchSize(r.width_, r.height_, 3));
  r.by_depth_.resize(r.max_depth_ + 1);
  return r;
}

uint64_t Relighter::CoefficientBytes(const LightTerms& terms) const {
  uint64_t n = 0;
  for (uint32_t j : terms.column) n += col_ptr_[j + 1] - col_ptr_[j];
  return n * (sizeof(uint32_t) + sizeof(float));
}

void Relighter::Relight(const LightTerms& terms, float* out) {
  for (auto& b : by_depth_) b.clear();
  int deepest = -1;
  for (size_t k = 0; k < terms.column.size(); ++k) {
    int d = depth_[terms.column[k]];
    by_depth_[d].push_back(static_cast<uint32_t>(k));
    deepest = std::max(deepest, d);
  }
  std::memset(out, 0, rows_ * 3 * sizeof(float));
  for (int d = deepest; d >= 0; --d) {
    for (uint32_t k : by_depth_[d]) {
      const uint32_t j = terms.column[k];
      const float w0 = terms.rgb[k * 3], w1 = terms.rgb[k * 3 + 1], w2 = terms.rgb[k * 3 + 2];
      const uint32_t* p = pos_.data() + col_ptr_[j];
      const float* v = values_.data() + col_ptr_[j];
      const uint64_t n = col_ptr_[j + 1] - col_ptr_[j];
      for (uint64_t e = 0; e < n; ++e) {
        float* o = out + static_cast<uint64_t>(p[e]) * 3;
        o[0] += w0 * v[e];
        o[1] += w1 * v[e];
        o[2] += w2 * v[e];
      }
    }
    if (d > 0) {  // Eq. 8: one single-step inverse column transform, depth d -> d - 1
      wavelet::SynthesisStep2D(col_filter_, out, width_, 3, bands_[d - 1].width, bands_[d - 1].height, scratch_.data());
    }
  }
}

Result<std::vector<float>> RelightStreaming(const std::string& path, const float* lighting, int jobs,
                                            const Progress& progress) {
  LTB_ASSIGN_OR_RETURN(io::ContainerReader in, io::ContainerReader::Open(path));
  LTB_RETURN_IF_ERROR(RequireCompleteF32Matrix(in));
  const ArraySpec& a = in.metadata().matrix();
  if (ColumnCodec::IsColumnTransformed(in.metadata())) {
    return InvalidArgument(path + ": streaming relighting takes uncompressed matrices (raw.ltm, rows.ltm, cols.ltm)");
  }
  std::vector<double> acc(a.rows * 3, 0.0);
  std::vector<uint64_t> chunks(a.ChunkCount());
  std::iota(chunks.begin(), chunks.end(), 0);
  if (a.layout == Layout::kRows) {
    LTB_RETURN_IF_ERROR(ParallelFor(chunks, jobs, progress, "chunks", [&](uint64_t c) -> Status {
      LTB_ASSIGN_OR_RETURN(io::Chunk chunk, in.ReadChunk(0, c));
      const ChunkExtent& e = chunk.extent();
      auto v = chunk.as<float>();
      for (uint64_t i = 0; i < e.rows; ++i) {
        double s0 = 0, s1 = 0, s2 = 0;
        const float* row = v.data() + i * a.cols;
        for (uint64_t j = 0; j < a.cols; ++j) {
          double t = row[j];
          s0 += t * lighting[j * 3];
          s1 += t * lighting[j * 3 + 1];
          s2 += t * lighting[j * 3 + 2];
        }
        acc[(e.row0 + i) * 3] = s0;
        acc[(e.row0 + i) * 3 + 1] = s1;
        acc[(e.row0 + i) * 3 + 2] = s2;
      }
      return Status::Ok();
    }));
  } else {
    // Column blocks: columns are summed in column order (one thread), so the result does
    // not depend on --jobs.
    for (uint64_t c : chunks) {
      if (progress.Cancelled()) return Cancelled("interrupted");
      LTB_ASSIGN_OR_RETURN(io::Chunk chunk, in.ReadChunk(0, c));
      const ChunkExtent& e = chunk.extent();
      auto v = chunk.as<float>();
      for (uint64_t k = 0; k < e.cols; ++k) {
        const uint64_t j = e.col0 + k;
        const double l0 = lighting[j * 3], l1 = lighting[j * 3 + 1], l2 = lighting[j * 3 + 2];
        if (l0 == 0 && l1 == 0 && l2 == 0) continue;
        const float* col = v.data() + k * a.rows;
        for (uint64_t i = 0; i < a.rows; ++i) {
          double t = col[i];
          acc[i * 3] += t * l0;
          acc[i * 3 + 1] += t * l1;
          acc[i * 3 + 2] += t * l2;
        }
      }
      progress.Report(c + 1, chunks.size(), "chunks");
    }
  }
  return std::vector<float>(acc.begin(), acc.end());
}

ImageErrors CompareImages(const float* image, const float* ref, uint64_t rows, uint64_t width, uint64_t height) {
  ImageErrors e;
  double d2 = 0, r2 = 0, peak = 0;
  for (uint64_t i = 0; i < rows * 3; ++i) {
    double d = static_cast<double>(image[i]) - ref[i];
    d2 += d * d;
    r2 += static_cast<double>(ref[i]) * ref[i];
    peak = std::max(peak, static_cast<double>(ref[i]));
  }
  e.rel_l2 = r2 > 0 ? std::sqrt(d2 / r2) : std::sqrt(d2);
  double mse = d2 / static_cast<double>(rows * 3);
  e.psnr = mse > 0 && peak > 0 ? 20.0 * std::log10(peak / std::sqrt(mse)) : INFINITY;
  if (width > 1 && height > 1 && width * height == rows) {
    double g2 = 0, gr2 = 0;
    for (uint64_t y = 0; y < height; ++y)
      for (uint64_t x = 0; x < width; ++x)
        for (int c = 0; c < 3; ++c) {
          uint64_t i = (y * width + x) * 3 + c;
          auto diff = [&](uint64_t j) {
            return (static_cast<double>(image[j]) - ref[j]) - (static_cast<double>(image[i]) - ref[i]);
          };
          auto rdiff = [&](uint64_t j) { return static_cast<double>(ref[j]) - ref[i]; };
          if (x + 1 < width) {
            double a = diff(i + 3), b = rdiff(i + 3);
            g2 += a * a;
            gr2 += b * b;
          }
          if (y + 1 < height) {
            double a = diff(i + width * 3), b = rdiff(i + width * 3);
            g2 += a * a;
            gr2 += b * b;
          }
        }
    e.rel_h1 = gr2 > 0 ? std::sqrt(g2 / gr2) : std::sqrt(g2);
  }
  return e;
}

Result<std::vector<uint8_t>> ReadRowMask(const io::ContainerReader& in) {
  const std::string& path = in.path();
  const Metadata& meta = in.metadata();
  std::vector<uint8_t> mask;
  const int m = meta.FindArray("mask");
  if (m < 0) return mask;
  const ArraySpec& s = meta.arrays[m];
  const uint64_t rows = meta.matrix().rows;
  if (s.dtype != DType::kU8 || s.cols != 1 || s.rows != rows || s.layout != Layout::kRows) {
    return DataLoss(path + ": side table \"mask\" is " + std::to_string(s.rows) + " x " + std::to_string(s.cols) + " " +
                    DTypeName(s.dtype) + ", not one u8 per row of the " + std::to_string(rows) + "-row matrix");
  }
  mask.reserve(rows);
  for (uint64_t c = 0; c < s.ChunkCount(); ++c) {
    LTB_ASSIGN_OR_RETURN(io::Chunk chunk, in.ReadChunk(static_cast<uint32_t>(m), c));
    auto v = chunk.as<uint8_t>();
    mask.insert(mask.end(), v.begin(), v.end());
  }
  if (mask.size() != rows) {
    return DataLoss(path + ": side table \"mask\" holds " + std::to_string(mask.size()) + " rows, not " +
                    std::to_string(rows));
  }
  return mask;
}

Result<std::vector<float>> ReadRowReflectance(const io::ContainerReader& in, uint64_t rows) {
  const std::string& path = in.path();
  const Metadata& meta = in.metadata();
  std::vector<float> refl;
  const int a = meta.FindArray("reflectance");
  if (a < 0) return refl;
  const ArraySpec& s = meta.arrays[a];
  if (s.dtype != DType::kF32 || s.cols != 3 || s.rows != rows || s.layout != Layout::kRows) {
    return DataLoss(path + ": side table \"reflectance\" is " + std::to_string(s.rows) + " x " +
                    std::to_string(s.cols) + " " + DTypeName(s.dtype) + ", not three f32 per row of the " +
                    std::to_string(rows) + "-row matrix");
  }
  refl.reserve(rows * 3);
  for (uint64_t c = 0; c < s.ChunkCount(); ++c) {
    LTB_ASSIGN_OR_RETURN(io::Chunk chunk, in.ReadChunk(static_cast<uint32_t>(a), c));
    auto v = chunk.as<float>();
    refl.insert(refl.end(), v.begin(), v.end());
  }
  if (refl.size() != rows * 3) {
    return DataLoss(path + ": side table \"reflectance\" holds " + std::to_string(refl.size()) + " values, not " +
                    std::to_string(rows * 3));
  }
  for (uint64_t i = 0; i < refl.size(); ++i) {
    if (!(refl[i] >= 0.0f) || !std::isfinite(refl[i])) {
      return DataLoss(path + ": side table \"reflectance\" row " + std::to_string(i / 3) + " channel " + "rgb"[i % 3] +
                      " is " + std::to_string(refl[i]) + " (expected a finite value >= 0)");
    }
  }
  return refl;
}

void ApplyReflectance(const std::vector<float>& reflectance, std::vector<float>* image) {
  if (reflectance.size() != image->size()) return;
  for (size_t i = 0; i < image->size(); ++i) (*image)[i] *= reflectance[i];
}

OutputFixes FinishRelitImage(const std::vector<uint8_t>& mask, bool keep_negative, std::vector<float>* image) {
  OutputFixes fixes;
  const uint64_t rows = image->size() / 3;
  float* px = image->data();
  if (mask.size() == rows) {
    for (uint64_t r = 0; r < rows; ++r) {
      if (mask[r] != 0) continue;
      px[3 * r] = px[3 * r + 1] = px[3 * r + 2] = 0.0f;
      ++fixes.masked_rows;
    }
  }
  if (!keep_negative) {  // branch-free, so it vectorises (-0 and NaN stay as they are)
    uint64_t clamped = 0;
    const uint64_t n = image->size();
#pragma omp simd reduction(+ : clamped)
    for (uint64_t i = 0; i < n; ++i) {
      const float v = px[i];
      clamped += v < 0.0f ? 1 : 0;
      px[i] = v < 0.0f ? 0.0f : v;
    }
    fixes.clamped_values = clamped;
  }
  return fixes;
}

int LightingExponent(const std::vector<float>& cubemap) {
  float peak = 0;
  for (float v : cubemap) peak = std::max(peak, std::abs(v));
  return LightingExponent(peak);
}

int LightingExponent(float peak) {
  constexpr int kHeadroom = 64;
  return std::isfinite(peak) && peak > std::ldexp(1.0f, kHeadroom) ? std::ilogb(peak) - kHeadroom + 1 : 0;
}

void ScaleByPowerOfTwo(std::vector<float>* values, int k) {
  if (k == 0) return;
  for (float& v : *values) v = std::ldexp(v, k);
}

}  // namespace ltb::stages
