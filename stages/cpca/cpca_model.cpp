#include "stages/cpca/cpca_model.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstring>

#include "stages/common/parallel_for.h"

namespace ltb::stages {

using namespace ltb::format;

CpcaLayout CpcaLayout::For(uint64_t k, uint64_t s, uint64_t n, uint64_t d, uint64_t row_align) {
  CpcaLayout l;
  l.k = k;
  l.s = s;
  l.n = n;
  l.d = d;
  ArraySpec& vec = l.vectors;
  vec.name = kCpcaVectorsArray;
  vec.dtype = DType::kF32;
  vec.rows = k * (s + 1);
  vec.cols = d;
  vec.layout = Layout::kRows;
  vec.block = BlockForTargetBytes(vec.rows, d, DType::kF32, Layout::kRows, 4ull << 20);
  ArraySpec& ids = l.ids;
  ids.name = kCpcaIdArray;
  ids.dtype = DType::kU32;
  ids.rows = n;
  ids.cols = 1;
  ids.layout = Layout::kRows;
  ids.block =
      std::min(n, std::max<uint64_t>(row_align, (4ull << 20) / (std::max<uint64_t>(s, 1) * 4) / row_align * row_align));
  ArraySpec& wts = l.weights;
  wts = ids;
  wts.name = kCpcaWeightsArray;
  wts.dtype = DType::kF32;
  wts.cols = s;
  return l;
}

nlohmann::json CpcaOutputMetadata(const CpcaLayout& l, const CpcaFitInfo& fit, const nlohmann::json& basis,
                                  const nlohmann::json& provenance) {
  const uint64_t k = l.k, s = l.s, n = l.n, d = l.d;
  nlohmann::json arrays = {l.vectors.ToJson(), l.ids.ToJson()};
  if (s > 0) arrays.push_back(l.weights.ToJson());
  const double final_err = fit.squared_error, final_norm = fit.squared_norm;
  const double rel = final_norm > 0 ? std::sqrt(final_err / final_norm) : std::sqrt(final_err);
  nlohmann::json meta = {{"arrays", arrays},
                         {"basis", basis},
                         {"cpca",
                          {{"clusters", k},
                           {"basis_dim", s},
                           {"rows", n},
                           {"dims", d},
                           {"iterations", fit.iterations},
                           {"growth_levels", fit.growth_levels},
                           {"seed", fit.seed},
                           {"relative_rms_error", rel},
                           {"squared_error", final_err},
                           {"squared_norm", final_norm},
                           {"empty_clusters", fit.empty_clusters},
                           {"vectors_array", kCpcaVectorsArray},
                           {"id_array", kCpcaIdArray},
                           {"weights_array", s > 0 ? nlohmann::json(kCpcaWeightsArray) : nlohmann::json(nullptr)},
                           {"decode",
                            "row r = v[c·(S+1)] + Σ_i w[r,i]·v[c·(S+1)+1+i], c = cluster_id[r], v = cluster_vectors "
                            "(docs/CPCA.md)"}}},
                         {"provenance", provenance}};
  if (fit.dense_first) {
    meta["cpca"]["dense_first"] = {
        {"dense_rows", fit.dense_rows}, {"dense_passes", fit.dense_passes}, {"final_passes", fit.final_passes}};
  }
  return meta;
}

Result<uint64_t> WriteCpcaVectors(io::ContainerWriter& out, const CpcaLayout& l,
                                  const std::function<void(uint64_t c, uint64_t i, float* out)>& vector) {
  const uint64_t s = l.s, d = l.d;
  uint64_t written = 0;
  for (uint64_t c : out.Missing(0)) {
    const ChunkExtent e = l.vectors.Extent(c);
    std::vector<float> v(e.rows * d);
    for (uint64_t r = 0; r < e.rows; ++r) vector((e.row0 + r) / (s + 1), (e.row0 + r) % (s + 1), v.data() + r * d);
    LTB_RETURN_IF_ERROR(out.Put(0, c, BytesOf(v)));
    written++;
  }
  return written;
}

Result<uint64_t> WriteCpcaRows(io::ContainerWriter& out, const CpcaLayout& l, int jobs, const CpcaRowEncoder& encode,
                               const std::function<void(uint64_t rows)>& done) {
  const uint64_t s = l.s;
  std::vector<uint64_t> row_chunks = out.Missing(1);
  if (s > 0) {
    for (uint64_t c : out.Missing(2)) row_chunks.push_back(c);
    std::sort(row_chunks.begin(), row_chunks.end());
    row_chunks.erase(std::unique(row_chunks.begin(), row_chunks.end()), row_chunks.end());
  }
  std::atomic<uint64_t> written{0};
  LTB_RETURN_IF_ERROR(ParallelFor(row_chunks, jobs, Progress{}, "chunks", [&](uint64_t c) -> Status {
    const ChunkExtent e = l.ids.Extent(c);
    std::vector<uint32_t> id(e.rows);
    std::vector<float> w(e.rows * s);
    LTB_RETURN_IF_ERROR(encode(e.row0, e.rows, id.data(), w.data()));
    if (!out.Has(1, c)) {
      LTB_RETURN_IF_ERROR(out.Put(1, c, BytesOf(id)));
      written++;
    }
    if (s > 0 && !out.Has(2, c)) {
      LTB_RETURN_IF_ERROR(out.Put(2, c, BytesOf(w)));
      written++;
    }
    done(e.rows);
    return Status::Ok();
  }));
  return written.load();
}

bool CpcaModel::IsCpca(const Metadata& meta) { return meta.json.contains("cpca") && meta.json["cpca"].is_object(); }

Result<CpcaModel> CpcaModel::Load(const io::ContainerReader& in, uint64_t mem_limit) {
  const Metadata& meta = in.metadata();
  const std::string& path = in.path();
  if (!IsCpca(meta)) return FailedPrecondition(path + ": is not a cpca output (no \"cpca\" metadata)");
  const auto& c = meta.json["cpca"];
  for (const char* key : {"clusters", "basis_dim", "rows", "dims"}) {
    if (!c.contains(key) || !c[key].is_number_unsigned()) {
      return DataLoss(path + ": metadata cpca." + key + " is missing or not a non-negative integer");
    }
  }
  CpcaModel m;
  m.path_ = path;
  m.k_ = c["clusters"].get<uint64_t>();
  m.s_ = c["basis_dim"].get<uint64_t>();
  m.n_ = c["rows"].get<uint64_t>();
  m.d_ = c["dims"].get<uint64_t>();
  m.error_ = c.value("relative_rms_error", 0.0);
  const ArraySpec& v = meta.matrix();
  if (v.name != kCpcaVectorsArray || v.dtype != DType::kF32 || v.layout != Layout::kRows || m.k_ == 0 ||
      v.rows != m.k_ * (m.s_ + 1) || v.cols != m.d_) {
    return DataLoss(path + ": array 0 is \"" + v.name + "\" " + std::to_string(v.rows) + "x" + std::to_string(v.cols) +
                    " " + DTypeName(v.dtype) + "; cpca metadata (K = " + std::to_string(m.k_) +
                    ", S = " + std::to_string(m.s_) + ", D = " + std::to_string(m.d_) + ") needs \"" +
                    kCpcaVectorsArray + "\" K·(S+1) x D f32 in row blocks");
  }
  m.id_array_ = meta.FindArray(kCpcaIdArray);
  if (m.id_array_ < 0) return DataLoss(path + ": has no \"" + std::string(kCpcaIdArray) + "\" array");
  const ArraySpec& ids = meta.arrays[m.id_array_];
  if (ids.dtype != DType::kU32 || ids.rows != m.n_ || ids.cols != 1 || ids.layout != Layout::kRows) {
    return DataLoss(path + ": array \"cluster_id\" is " + std::to_string(ids.rows) + "x" + std::to_string(ids.cols) +
                    " " + DTypeName(ids.dtype) + "; expected " + std::to_string(m.n_) + "x1 u32 in row blocks");
  }
  m.row_spec_ = ids;
  if (m.s_ > 0) {
    m.weight_array_ = meta.FindArray(kCpcaWeightsArray);
    if (m.weight_array_ < 0) return DataLoss(path + ": has no \"" + std::string(kCpcaWeightsArray) + "\" array");
    const ArraySpec& w = meta.arrays[m.weight_array_];
    if (w.dtype != DType::kF32 || w.rows != m.n_ || w.cols != m.s_ || w.layout != Layout::kRows ||
        w.block != ids.block) {
      return DataLoss(path + ": array \"weights\" is " + std::to_string(w.rows) + "x" + std::to_string(w.cols) + " " +
                      DTypeName(w.dtype) + " (block " + std::to_string(w.block) + "); expected " +
                      std::to_string(m.n_) + "x" + std::to_string(m.s_) + " f32 in row blocks of " +
                      std::to_string(ids.block));
    }
  }
  if (!in.complete()) {
    return FailedPrecondition(path + ": is incomplete; rerun the `ltbake cpca` command that writes it to finish it");
  }
  uint64_t bytes = v.rows * v.cols * 4;
  if (bytes > mem_limit) {
    return FailedPrecondition(path + ": its means and directions take " + std::to_string(bytes >> 20) +
                              " MiB, more than --mem-limit (" + std::to_string(mem_limit >> 20) +
                              " MiB); raise --mem-limit");
  }
  m.vectors_.resize(v.rows * v.cols);
  for (uint64_t ch = 0; ch < v.ChunkCount(); ++ch) {
    LTB_ASSIGN_OR_RETURN(io::Chunk chunk, in.ReadChunk(0, ch));
    auto f = chunk.as<float>();
    std::memcpy(m.vectors_.data() + chunk.extent().row0 * v.cols, f.data(), f.size() * 4);
  }
  const auto& basis = meta.json.value("basis", nlohmann::json::object());
  if (basis.is_object() && basis.contains("rows") && basis["rows"].is_object() &&
      basis["rows"].value("kind", "") == "image") {
    const auto& r = basis["rows"];
    if (r.contains("width") && r.contains("height") && r["width"].is_number_unsigned() &&
        r["height"].is_number_unsigned() && r["width"].get<uint64_t>() * r["height"].get<uint64_t>() == m.n_) {
      m.image_ = std::make_pair(r["width"].get<uint64_t>(), r["height"].get<uint64_t>());
    }
  }
  return m;
}

Status CpcaModel::ReadRows(const io::ContainerReader& in, uint64_t chunk, std::vector<uint32_t>* ids,
                           std::vector<float>* weights) const {
  LTB_ASSIGN_OR_RETURN(io::Chunk ic, in.ReadChunk(static_cast<uint32_t>(id_array_), chunk));
  auto iv = ic.as<uint32_t>();
  const ChunkExtent e = ic.extent();
  for (uint64_t r = 0; r < e.rows; ++r) {
    if (iv[r] >= k_) {
      return DataLoss(path_ + ": row " + std::to_string(e.row0 + r) + " has cluster id " + std::to_string(iv[r]) +
                      "; the file has " + std::to_string(k_) + " clusters");
    }
  }
  ids->assign(iv.begin(), iv.end());
  weights->clear();
  if (s_ > 0) {
    LTB_ASSIGN_OR_RETURN(io::Chunk wc, in.ReadChunk(static_cast<uint32_t>(weight_array_), chunk));
    auto wv = wc.as<float>();
    weights->assign(wv.begin(), wv.end());
  }
  return Status::Ok();
}

Status CpcaModel::DecodeChunk(const io::ContainerReader& in, uint64_t chunk, std::vector<float>* out) const {
  std::vector<uint32_t> ids;
  std::vector<float> w;
  LTB_RETURN_IF_ERROR(ReadRows(in, chunk, &ids, &w));
  out->resize(ids.size() * d_);
  std::vector<double> acc(d_);
  for (uint64_t r = 0; r < ids.size(); ++r) {
    const float* mean = vector(ids[r], 0);
    for (uint64_t j = 0; j < d_; ++j) acc[j] = mean[j];
    for (uint64_t i = 0; i < s_; ++i) {
      const double wi = w[r * s_ + i];
      const float* b = vector(ids[r], i + 1);
      for (uint64_t j = 0; j < d_; ++j) acc[j] += wi * b[j];
    }
    float* o = out->data() + r * d_;
    for (uint64_t j = 0; j < d_; ++j) o[j] = static_cast<float>(acc[j]);
  }
  return Status::Ok();
}

Result<CpcaRelighter> CpcaRelighter::Load(const std::string& path, uint64_t mem_limit) {
  LTB_ASSIGN_OR_RETURN(io::ContainerReader in, io::ContainerReader::Open(path));
  CpcaRelighter r;
  LTB_ASSIGN_OR_RETURN(r.model_, CpcaModel::Load(in, mem_limit));
  const CpcaModel& m = r.model_;
  uint64_t need = m.clusters() * (m.basis() + 1) * m.dims() * 4 + m.rows() * (m.basis() + 1) * 4;
  if (need > mem_limit) {
    return FailedPrecondition(path + ": model, ids and weights take " + std::to_string(need >> 20) +
                              " MiB, more than --mem-limit (" + std::to_string(mem_limit >> 20) +
                              " MiB); raise --mem-limit");
  }
  r.ids_.reserve(m.rows());
  r.weights_.reserve(m.rows() * m.basis());
  std::vector<uint32_t> ids;
  std::vector<float> w;
  for (uint64_t c = 0; c < m.row_chunks(); ++c) {
    LTB_RETURN_IF_ERROR(m.ReadRows(in, c, &ids, &w));
    r.ids_.insert(r.ids_.end(), ids.begin(), ids.end());
    r.weights_.insert(r.weights_.end(), w.begin(), w.end());
  }
  return r;
}

void CpcaRelighter::Blend(const std::vector<double>& p, float* out) const {
  const uint64_t s = model_.basis();
  for (uint64_t r = 0; r < ids_.size(); ++r) {
    const double* pc = p.data() + ids_[r] * (s + 1) * 3;
    double o0 = pc[0], o1 = pc[1], o2 = pc[2];
    const float* w = weights_.data() + r * s;
    for (uint64_t i = 0; i < s; ++i) {
      o0 += w[i] * pc[(i + 1) * 3];
      o1 += w[i] * pc[(i + 1) * 3 + 1];
      o2 += w[i] * pc[(i + 1) * 3 + 2];
    }
    out[r * 3] = static_cast<float>(o0);
    out[r * 3 + 1] = static_cast<float>(o1);
    out[r * 3 + 2] = static_cast<float>(o2);
  }
}

void CpcaRelighter::Relight(const float* lighting, float* out) const {
  const uint64_t vecs = model_.clusters() * (model_.basis() + 1), d = model_.dims();
  std::vector<double> p(vecs * 3, 0.0);
  for (uint64_t v = 0; v < vecs; ++v) {
    const float* b = model_.vector(0, 0) + v * d;
    double s0 = 0, s1 = 0, s2 = 0;
    for (uint64_t j = 0; j < d; ++j) {
      s0 += static_cast<double>(b[j]) * lighting[j * 3];
      s1 += static_cast<double>(b[j]) * lighting[j * 3 + 1];
      s2 += static_cast<double>(b[j]) * lighting[j * 3 + 2];
    }
    p[v * 3] = s0;
    p[v * 3 + 1] = s1;
    p[v * 3 + 2] = s2;
  }
  Blend(p, out);
}

void CpcaRelighter::RelightTerms(const std::vector<uint32_t>& columns, const std::vector<float>& rgb,
                                 float* out) const {
  const uint64_t vecs = model_.clusters() * (model_.basis() + 1), d = model_.dims();
  std::vector<double> p(vecs * 3, 0.0);
  for (uint64_t v = 0; v < vecs; ++v) {
    const float* b = model_.vector(0, 0) + v * d;
    double s0 = 0, s1 = 0, s2 = 0;
    for (size_t t = 0; t < columns.size(); ++t) {
      const double bj = b[columns[t]];
      s0 += bj * rgb[t * 3];
      s1 += bj * rgb[t * 3 + 1];
      s2 += bj * rgb[t * 3 + 2];
    }
    p[v * 3] = s0;
    p[v * 3 + 1] = s1;
    p[v * 3 + 2] = s2;
  }
  Blend(p, out);
}

}  // namespace ltb::stages
