#include "stages/triple/material.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <mutex>
#include <numbers>
#include <vector>

#include "format/bits.h"
#include "format/io/container_writer.h"
#include "format/io/file.h"
#include "format/version.h"
#include "stages/common/cubemap.h"
#include "stages/common/parallel_for.h"

namespace ltb::triple {

Result<Brdf> ParseBrdf(const std::string& text) {
  Brdf b;
  std::vector<std::string> parts;
  size_t start = 0;
  for (size_t k = 0; k <= text.size(); ++k) {
    if (k == text.size() || text[k] == ':') {
      parts.push_back(text.substr(start, k - start));
      start = k + 1;
    }
  }
  auto number = [&](size_t i, double* out) -> Status {
    char* end = nullptr;
    const double v = std::strtod(parts[i].c_str(), &end);
    if (parts[i].empty() || *end != '\0' || !std::isfinite(v) || v < 0) {
      return InvalidArgument("--brdf " + text + ": '" + parts[i] + "' is not a non-negative number");
    }
    *out = v;
    return Status::Ok();
  };
  if (parts[0] == "lambert" && parts.size() <= 2) {
    b.kind = Brdf::Kind::kLambert;
    if (parts.size() == 2) LTB_RETURN_IF_ERROR(number(1, &b.albedo));
    return b;
  }
  if (parts[0] == "phong" && (parts.size() == 2 || parts.size() == 3)) {
    b.kind = Brdf::Kind::kPhong;
    LTB_RETURN_IF_ERROR(number(1, &b.exponent));
    if (parts.size() == 3) LTB_RETURN_IF_ERROR(number(2, &b.albedo));
    return b;
  }
  return InvalidArgument("--brdf " + text + ": expected lambert[:ALBEDO] or phong:EXPONENT[:KS]");
}

double BrdfValue(const Brdf& brdf, const glm::dvec3& dir, const glm::dvec3& w) {
  const double c = glm::dot(dir, w);
  if (c <= 0) return 0;
  return brdf.kind == Brdf::Kind::kLambert
             ? brdf.albedo / std::numbers::pi * c
             : brdf.albedo * (brdf.exponent + 1) / (2 * std::numbers::pi) * std::pow(c, brdf.exponent);
}

CubeFaces MaterialFaces(const Brdf& brdf, const glm::dvec3& dir, uint64_t res) {
  CubeFaces faces;
  const uint32_t r = static_cast<uint32_t>(res);
  std::vector<double> pixels(res * res);
  const double area = static_cast<double>(res * res);  // texel solid angle × R²: unit-square measure
  for (int f = 0; f < 6; ++f) {
    for (uint32_t t = 0; t < r; ++t) {
      for (uint32_t s = 0; s < r; ++s) {
        const cubemap::Texel x{f, s, t};
        pixels[t * res + s] = BrdfValue(brdf, dir, cubemap::TexelCenter(x, r)) * cubemap::TexelSolidAngle(x, r) * area;
      }
    }
    faces[f] = HaarFace::Forward(pixels, res);
  }
  return faces;
}

CubeFaces CubeFunctionFaces(const double* values, uint64_t res) {
  CubeFaces faces;
  for (int f = 0; f < 6; ++f) {
    faces[f] = HaarFace::Forward(std::span<const double>(values + f * res * res, res * res), res);
  }
  return faces;
}

double CubeTripleProduct(const CubeFaces& l, const CubeFaces& v, const CubeFaces& rho) {
  double b = 0;
  for (int f = 0; f < 6; ++f) b += LinearTripleProduct(l[f], v[f], rho[f]);
  return b;
}

namespace {

std::string BrdfName(const Brdf& b) { return b.kind == Brdf::Kind::kLambert ? "lambert" : "phong"; }

// One row: the Haar coefficients of ρ̃ for `dir` on the six faces, the smallest ones zeroed
// so that the kept ones hold at least `energy` of Σc². Returns the kept fraction.
double MaterialRow(const Brdf& brdf, const glm::dvec3& dir, uint64_t res, double energy, float* out, uint64_t* kept) {
  const CubeFaces faces = MaterialFaces(brdf, dir, res);
  const uint64_t face = res * res, n = 6 * face;
  std::vector<double> c(n);
  for (int f = 0; f < 6; ++f) std::copy(faces[f].c.begin(), faces[f].c.end(), c.begin() + f * face);
  std::vector<uint32_t> order(n);
  for (uint32_t k = 0; k < n; ++k) order[k] = k;
  std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) {
    const double x = c[a] * c[a], y = c[b] * c[b];
    return x != y ? x > y : a < b;
  });
  double total = 0;
  for (double v : c) total += v * v;
  double sum = 0;
  uint64_t m = 0;
  while (m < n && total > 0 && sum < energy * total) {
    const double v = c[order[m++]];
    sum += v * v;
  }
  std::fill(out, out + n, 0.0f);
  for (uint64_t k = 0; k < m; ++k) out[order[k]] = static_cast<float>(c[order[k]]);
  *kept += m;
  return total > 0 ? sum / total : 1.0;
}

}  // namespace

Result<MaterialResult> RunMaterial(const MaterialOptions& o, const Progress& progress) {
  const uint64_t res = o.cube_res;
  if (!IsPowerOfTwo(res) || res > 512) {
    return InvalidArgument("--cube-res " + std::to_string(res) + " is not a power of two up to 512");
  }
  const uint64_t sres = o.samples_res != 0 ? o.samples_res : o.brdf.kind == Brdf::Kind::kLambert ? 16 : 32;
  if (sres > 512) return InvalidArgument("--samples-res " + std::to_string(sres) + " is above 512");
  if (!(o.energy > 0 && o.energy <= 1)) {
    return InvalidArgument("--energy " + std::to_string(o.energy) + " is not in (0, 1]");
  }
  const uint64_t rows = 6 * sres * sres, cols = 6 * res * res;
  format::ArraySpec spec;
  spec.name = "matrix";
  spec.rows = rows;
  spec.cols = cols;
  spec.block = format::BlockForTargetBytes(rows, cols, format::DType::kF32, format::Layout::kRows, 4ull << 20);
  LTB_RETURN_IF_ERROR(spec.Validate().WithContext(o.output));
  nlohmann::json brdf = {{"kind", BrdfName(o.brdf)}, {"albedo", o.brdf.albedo}};
  if (o.brdf.kind == Brdf::Kind::kPhong) brdf["exponent"] = o.brdf.exponent;
  nlohmann::json meta = {
      {"arrays", {spec.ToJson()}},
      {"basis",
       {{"rows",
         {{"kind", "cubemap"},
          {"cube_res", sres},
          {"basis", "pixel"},
          {"role", o.brdf.kind == Brdf::Kind::kLambert ? "normal" : "reflection"}}},
        {"cols", {{"kind", "cubemap"}, {"cube_res", res}, {"basis", "haar-squares"}}}}},
      {"material", {{"brdf", brdf}, {"energy", o.energy}, {"samples_res", sres}}},
      {"provenance",
       {{"tool", std::string("ltbake ") + kToolVersion},
        {"stage", "material"},
        {"parameters", {{"cube_res", res}, {"samples_res", sres}, {"energy", o.energy}, {"brdf", brdf}}}}},
  };
  io::WriterOptions wo;
  wo.overwrite_mismatch = o.overwrite;
  LTB_ASSIGN_OR_RETURN(io::ContainerWriter writer, io::ContainerWriter::Open(o.output, meta, wo));
  MaterialResult result;
  result.rows = rows;
  result.cols = cols;
  result.samples_res = sres;
  result.chunks_already_committed = writer.resume_info().committed_chunks;
  const std::vector<uint64_t> missing = writer.Missing(0);
  std::mutex mu;
  format::EncodeOptions eo;
  eo.sparse = true;
  eo.zstd = true;
  eo.dtype = format::DType::kF32;
  const uint32_t sr = static_cast<uint32_t>(sres);
  LTB_RETURN_IF_ERROR(
      stages::ParallelFor(missing, std::max(1, o.jobs), progress, "chunks", [&](uint64_t chunk) -> Status {
        const format::ChunkExtent e = spec.Extent(chunk);
        std::vector<float> values(e.rows * cols);
        uint64_t kept = 0;
        double worst = 1;
        for (uint64_t r = 0; r < e.rows; ++r) {
          const glm::dvec3 dir = cubemap::TexelCenter(cubemap::ColumnToTexel(e.row0 + r, sr), sr);
          worst = std::min(worst, MaterialRow(o.brdf, dir, res, o.energy, values.data() + r * cols, &kept));
        }
        LTB_RETURN_IF_ERROR(writer.Put(
            0, chunk, format::ByteSpan(reinterpret_cast<const std::byte*>(values.data()), values.size() * 4), eo));
        std::lock_guard<std::mutex> lock(mu);
        result.terms_kept += kept;
        result.worst_energy_kept = std::min(result.worst_energy_kept, worst);
        result.chunks_written++;
        return Status::Ok();
      }));
  LTB_RETURN_IF_ERROR(writer.Finish());
  LTB_ASSIGN_OR_RETURN(io::File f, io::File::Open(o.output, io::File::Mode::kRead));
  LTB_ASSIGN_OR_RETURN(result.file_bytes, f.Size());
  return result;
}

}  // namespace ltb::triple
