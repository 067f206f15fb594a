#include "stages/column_transform/column_codec.h"

#include <array>
#include <cmath>
#include <cstring>

#include "stages/common/basis.h"

namespace ltb::stages {

using namespace ltb::format;

bool ColumnCodec::IsColumnTransformed(const Metadata& meta) {
  return meta.json.contains("column_transform") && meta.json["column_transform"].is_object();
}

Result<ColumnCodec> ColumnCodec::FromMetadata(const Metadata& meta, const std::string& path) {
  if (!IsColumnTransformed(meta)) return FailedPrecondition(path + ": is not a column-transform or quantize output");
  const auto& ct = meta.json["column_transform"];
  auto bad = [&](const std::string& what) { return DataLoss(path + ": column_transform metadata: " + what); };
  ColumnCodec c;
  if (!ct.contains("filter") || !ct["filter"].is_string()) return bad("no filter");
  auto f = wavelet::ParseFilter(ct["filter"].get<std::string>());
  if (!f.ok()) return bad(f.status().message());
  c.filter_ = *f;
  if (!ct.contains("image") || !ct["image"].is_object() ||
      !ct["image"].value("width", nlohmann::json()).is_number_unsigned() ||
      !ct["image"].value("height", nlohmann::json()).is_number_unsigned()) {
    return bad("no image size");
  }
  c.width_ = ct["image"]["width"].get<uint64_t>();
  c.height_ = ct["image"]["height"].get<uint64_t>();
  if (c.width_ == 0 || c.height_ == 0 || c.width_ * c.height_ != meta.matrix().rows) {
    return bad("image " + std::to_string(c.width_) + "x" + std::to_string(c.height_) + " does not match " +
               std::to_string(meta.matrix().rows) + " rows");
  }
  if (!ct.value("max_depth", nlohmann::json()).is_number_unsigned()) return bad("no max_depth");
  c.max_depth_ = ct["max_depth"].get<int>();
  if (c.max_depth_ > wavelet::MaxDepth(c.width_, c.height_)) return bad("max_depth beyond the image");
  if (c.max_depth_ > 0 && !wavelet::CheckSize(c.filter_, c.width_, c.height_).ok())
    return bad("filter and size disagree");
  c.depth_array_ = meta.FindArray(ct.value("depth_array", std::string("depth")));
  if (c.depth_array_ < 0) return bad("no depth array");
  const ArraySpec& ds = meta.arrays[c.depth_array_];
  // Chunked like the matrix (column-transform) or in few chunks of its own (quantize since
  // 2026-12-02): readers take a chunk's columns with ReadLines.
  if (ds.dtype != DType::kU8 || ds.rows != meta.matrix().cols || ds.cols != 1 || ds.layout != Layout::kRows) {
    return bad("depth array has an unexpected shape");
  }
  if (meta.matrix().layout != Layout::kCols) return bad("matrix is not in column blocks");
  if (meta.json.contains("quantization")) {
    const auto& q = meta.json["quantization"];
    if (!q.is_object() || !q.value("bits", nlohmann::json()).is_number_unsigned())
      return bad("quantization without bits");
    c.quant_.bits = q["bits"].get<int>();
    if (c.quant_.bits < 2 || c.quant_.bits > 24) return bad("bits " + std::to_string(c.quant_.bits));
    auto scaling = ParseScaling(q.value("scaling", std::string("?")));
    if (!scaling.ok()) return bad(scaling.status().message());
    c.quant_.scaling = *scaling;
    c.quant_.dither = q.value("dither", true);
    c.quant_.seed = q.value("seed", uint64_t{0});
    if (!q.contains("scale_array")) {  // one step Δ for the matrix: M = Δ · Q in every column
      const auto& step = q.value("step", nlohmann::json());
      if (!step.is_number() || !(step.get<double>() > 0) || !std::isfinite(step.get<double>()))
        return bad("neither a scale array nor a step");
      c.uniform_scale_ = step.get<double>() * c.quant_.Levels();
    } else {
      c.scale_array_ = meta.FindArray(q.value("scale_array", std::string("scale")));
      if (c.scale_array_ < 0) return bad("no scale array");
      const ArraySpec& ss = meta.arrays[c.scale_array_];
      if (ss.dtype != DType::kF64 || ss.rows != meta.matrix().cols || ss.cols != 1 || ss.layout != Layout::kRows) {
        return bad("scale array has an unexpected shape");
      }
    }
    if (meta.matrix().dtype != DType::kI32) return bad("quantized matrix is not i32");
  } else if (meta.matrix().dtype != DType::kF32) {
    return bad("matrix is not f32");
  }
  auto tables = std::make_shared<Tables>();
  if (c.quant_.bits > 0) {
    tables->factors = QuantizationFactors(c.filter_, c.width_, c.height_, c.max_depth_, c.quant_.scaling);
  }
  c.tables_ = std::move(tables);
  return c;
}

std::vector<uint8_t> ColumnCodec::ComputeLevels(uint64_t width, uint64_t height, int depth) {
  std::vector<uint8_t> lv(width * height, 0);
  auto bands = wavelet::BandSizes(width, height, depth);
  // Detail bands of step s (1-based) lie in bands[s-1] minus bands[s]: level depth − s.
  for (int s = 1; s <= depth; ++s) {
    const auto& in = bands[s - 1];
    const auto& lo = bands[s];
    for (uint64_t y = 0; y < in.height; ++y)
      for (uint64_t x = 0; x < in.width; ++x)
        if (x >= lo.width || y >= lo.height) lv[y * width + x] = static_cast<uint8_t>(depth - s);
  }
  return lv;
}

std::vector<std::vector<double>> SynthesisEnergies(wavelet::Filter filter, uint64_t width, uint64_t height,
                                                   int max_depth) {
  const uint64_t pixels = width * height;
  std::vector<std::vector<double>> out(max_depth + 1, std::vector<double>(pixels, 1.0));
  if (wavelet::IsOrthonormal(filter) || max_depth == 0) return out;
  auto bands = wavelet::BandSizes(width, height, max_depth);
  std::vector<double> img(pixels), scratch(wavelet::ScratchSize(width, height, 1));
  auto synth_norm = [&](int step, uint64_t x, uint64_t y) {
    std::fill(img.begin(), img.end(), 0.0);
    img[y * width + x] = 1.0;
    for (int l = step; l-- > 0;) {
      wavelet::SynthesisStep2D(filter, img.data(), width, 1, bands[l].width, bands[l].height, scratch.data());
    }
    double s = 0;
    for (double v : img) s += v * v;
    return s;
  };
  // detail[s]: the three high bands of step s (HL, LH, HH); unused when a band is empty.
  std::vector<std::array<double, 3>> detail(max_depth + 1);
  for (int s = 1; s <= max_depth; ++s) {
    const auto& in = bands[s - 1];
    const auto& lo = bands[s];
    if (in.width > lo.width) detail[s][0] = synth_norm(s, (lo.width + in.width) / 2, lo.height / 2);
    if (in.height > lo.height) detail[s][1] = synth_norm(s, lo.width / 2, (lo.height + in.height) / 2);
    if (in.width > lo.width && in.height > lo.height) {
      detail[s][2] = synth_norm(s, (lo.width + in.width) / 2, (lo.height + in.height) / 2);
    }
  }
  for (int d = 1; d <= max_depth; ++d) {
    std::vector<double>& w = out[d];
    for (int s = 1; s <= d; ++s) {
      const auto& in = bands[s - 1];
      const auto& lo = bands[s];
      for (uint64_t y = 0; y < in.height; ++y)
        for (uint64_t x = 0; x < in.width; ++x) {
          if (x < lo.width && y < lo.height) continue;
          w[y * width + x] = detail[s][x >= lo.width ? (y >= lo.height ? 2 : 0) : 1];
        }
    }
    double low = synth_norm(d, bands[d].width / 2, bands[d].height / 2);
    for (uint64_t y = 0; y < bands[d].height; ++y)
      for (uint64_t x = 0; x < bands[d].width; ++x) w[y * width + x] = low;
  }
  return out;
}

std::vector<std::vector<double>> QuantizationFactors(wavelet::Filter filter, uint64_t width, uint64_t height,
                                                     int max_depth, Scaling scaling) {
  const uint64_t pixels = width * height;
  std::vector<std::vector<double>> f(max_depth + 1, std::vector<double>(pixels, 1.0));
  if (scaling == Scaling::kNone) return f;
  if (scaling == Scaling::kNormLevel || scaling == Scaling::kNorm)
    f = SynthesisEnergies(filter, width, height, max_depth);
  if (scaling == Scaling::kNorm) {
    for (auto& fd : f)
      for (double& v : fd) v = std::sqrt(v);
    return f;
  }
  for (int d = 0; d <= max_depth; ++d) {
    auto lv = ColumnCodec::ComputeLevels(width, height, d);
    for (uint64_t p = 0; p < pixels; ++p) f[d][p] = std::ldexp(std::sqrt(f[d][p]), lv[p]);
  }
  return f;
}

Result<Scaling> ParseScaling(const std::string& name) {
  for (Scaling s : {Scaling::kNone, Scaling::kLevel, Scaling::kNormLevel, Scaling::kNorm})
    if (name == ScalingName(s)) return s;
  return InvalidArgument("scaling \"" + name + "\" is unknown (written by a newer ltbake?)");
}

const char* ScalingName(Scaling s) {
  switch (s) {
    case Scaling::kNone:
      return "none";
    case Scaling::kLevel:
      return "level";
    case Scaling::kNormLevel:
      return "norm-level";
    case Scaling::kNorm:
      return "norm";
  }
  return "?";
}

void ColumnCodec::DenseCoefficients(int depth, double scale, const uint32_t* index, const void* values, size_t n,
                                    float* out) const {
  std::memset(out, 0, width_ * height_ * sizeof(float));
  if (quant_.bits == 0) {
    const float* v = static_cast<const float*>(values);
    for (size_t i = 0; i < n; ++i) out[index[i]] = v[i];
    return;
  }
  const int32_t* q = static_cast<const int32_t*>(values);
  const double step = scale / quant_.Levels();
  const std::vector<double>& f = Factors(depth);
  for (size_t i = 0; i < n; ++i) out[index[i]] = static_cast<float>(static_cast<double>(q[i]) * step / f[index[i]]);
}

void ColumnCodec::ToImage(int depth, float* column, std::vector<float>* scratch) const {
  if (depth == 0) return;
  scratch->resize(wavelet::ScratchSize(width_, height_, 1));
  wavelet::Inverse2D(filter_, column, width_, height_, 1, depth, scratch->data());
}

Status ColumnCodec::DecodeChunk(const io::ContainerReader& reader, uint64_t chunk, std::vector<float>* out,
                                const io::ReadOptions& options) const {
  LTB_ASSIGN_OR_RETURN(SparseChunk sc, reader.ReadSparse(0, chunk, options));
  const ChunkExtent& e = sc.extent;
  LTB_ASSIGN_OR_RETURN(const std::vector<uint8_t> depths,
                       ReadLinesAs<uint8_t>(reader, depth_array_, e.col0, e.col0 + e.cols, options));
  std::vector<double> scales;
  if (scale_array_ >= 0) {
    LTB_ASSIGN_OR_RETURN(scales, ReadLinesAs<double>(reader, scale_array_, e.col0, e.col0 + e.cols, options));
  }
  const uint64_t pixels = width_ * height_;
  out->assign(e.cols * pixels, 0.0f);
  std::vector<float> scratch;
  const size_t elem = 4;  // f32 values or i32 quantized values
  size_t pos = 0;
  for (uint64_t k = 0; k < e.cols; ++k) {
    int d = depths[k];
    if (d > max_depth_) {
      return DataLoss(reader.path() + ": column " + std::to_string(e.col0 + k) + " has depth " + std::to_string(d) +
                      ", over max_depth " + std::to_string(max_depth_));
    }
    size_t begin = pos;
    while (pos < sc.index.size() && sc.index[pos] < (k + 1) * pixels) ++pos;
    std::vector<uint32_t> local(sc.index.begin() + begin, sc.index.begin() + pos);
    for (uint32_t& i : local) i -= static_cast<uint32_t>(k * pixels);
    double scale = !scales.empty() ? scales[k] : uniform_scale_ > 0 ? uniform_scale_ : 1.0;
    if (!std::isfinite(scale) || scale < 0) {
      return DataLoss(reader.path() + ": column " + std::to_string(e.col0 + k) + " has scale " + std::to_string(scale));
    }
    float* col = out->data() + k * pixels;
    DenseCoefficients(d, scale, local.data(), sc.values.data() + begin * elem, local.size(), col);
    ToImage(d, col, &scratch);
  }
  return Status::Ok();
}

}  // namespace ltb::stages
