#include "stages/triple/material.h"

#include <algorithm>
#include <atomic>
#include <cmath>
#include <cstdio>
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

TexelTable::TexelTable(uint64_t r) : res(r) {
  const uint32_t rr = static_cast<uint32_t>(r);
  const double area = static_cast<double>(r * r);  // texel solid angle × R²: unit-square measure
  for (uint64_t c = 0; c < 6 * r * r; ++c) {
    const cubemap::Texel x = cubemap::ColumnToTexel(c, rr);
    centre.push_back(cubemap::TexelCenter(x, rr));
    weight.push_back(cubemap::TexelSolidAngle(x, rr) * area);
  }
}

CubeFaces MaterialFaces(const Brdf& brdf, const glm::dvec3& n, const glm::dvec3& wr, const TexelTable& texels) {
  CubeFaces faces;
  const uint64_t res = texels.res, face = res * res;
  std::vector<double> pixels(face);
  for (uint64_t f = 0; f < 6; ++f) {
    for (uint64_t p = 0; p < face; ++p) {
      pixels[p] = BrdfValue(brdf, n, wr, texels.centre[f * face + p]) * texels.weight[f * face + p];
    }
    faces[f] = HaarFace::Forward(pixels, res);
  }
  return faces;
}

CubeFaces MaterialFaces(const Brdf& brdf, const glm::dvec3& n, const glm::dvec3& wr, uint64_t res) {
  return MaterialFaces(brdf, n, wr, TexelTable(res));
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

// One row: the Haar coefficients of ρ̃ for (normal, wr) on the six faces, the smallest ones zeroed
// so that the kept ones hold at least `energy` of Σc². Returns the kept fraction.
double MaterialRow(const Brdf& brdf, const glm::dvec3& normal, const glm::dvec3& wr, const TexelTable& texels,
                   double energy, float* out, uint64_t* kept) {
  const CubeFaces faces = MaterialFaces(brdf, normal, wr, texels);
  const uint64_t face = texels.res * texels.res, n = 6 * face;
  std::vector<double> c(n);
  for (int f = 0; f < 6; ++f) std::copy(faces[f].c.begin(), faces[f].c.end(), c.begin() + f * face);
  std::vector<uint32_t> order;  // the nonzero coefficients, largest first
  for (uint32_t k = 0; k < n; ++k) {
    if (c[k] != 0) order.push_back(k);
  }
  std::sort(order.begin(), order.end(), [&](uint32_t a, uint32_t b) {
    const double x = c[a] * c[a], y = c[b] * c[b];
    return x != y ? x > y : a < b;
  });
  double total = 0;
  for (double v : c) total += v * v;
  double sum = 0;
  uint64_t m = 0;
  while (m < order.size() && total > 0 && sum < energy * total) {
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
  const bool two = o.brdf.TwoDirections();
  const uint64_t sres = o.samples_res != 0 ? o.samples_res : o.brdf.kind == Brdf::Kind::kPhong ? 32 : 16;
  const uint64_t nres = two ? (o.normals_res != 0 ? o.normals_res : 4) : 0;
  if (sres > 512) return InvalidArgument("--samples-res " + std::to_string(sres) + " is above 512");
  if (nres > 64) return InvalidArgument("--normals-res " + std::to_string(nres) + " is above 64");
  if (!two && o.normals_res != 0) {
    return InvalidArgument(std::string("--normals-res is for the BRDFs of two directions (blinn, ward, "
                                       "cook-torrance); ") +
                           BrdfKindName(o.brdf.kind) + " has one");
  }
  if (!(o.energy > 0 && o.energy <= 1)) {
    return InvalidArgument("--energy " + std::to_string(o.energy) + " is not in (0, 1]");
  }
  const uint64_t per_normal = 6 * sres * sres, rows = two ? 6 * nres * nres * per_normal : per_normal;
  const uint64_t cols = 6 * res * res;
  format::ArraySpec spec;
  spec.name = "matrix";
  spec.rows = rows;
  spec.cols = cols;
  spec.block = format::BlockForTargetBytes(rows, cols, format::DType::kF32, format::Layout::kRows, 4ull << 20);
  LTB_RETURN_IF_ERROR(spec.Validate().WithContext(o.output));
  nlohmann::json brdf = {{"kind", BrdfKindName(o.brdf.kind)}, {"albedo", o.brdf.albedo}};
  if (o.brdf.kind == Brdf::Kind::kPhong || o.brdf.kind == Brdf::Kind::kBlinn) brdf["exponent"] = o.brdf.exponent;
  if (o.brdf.kind == Brdf::Kind::kWard || o.brdf.kind == Brdf::Kind::kCookTorrance) {
    brdf["roughness"] = o.brdf.roughness;
  }
  if (o.brdf.kind == Brdf::Kind::kCookTorrance) brdf["f0"] = o.brdf.f0;
  const char* role = o.brdf.kind == Brdf::Kind::kLambert ? "normal" : two ? "normal-reflection" : "reflection";
  nlohmann::json material = {{"brdf", brdf}, {"energy", o.energy}, {"samples_res", sres}};
  nlohmann::json params = {{"cube_res", res}, {"samples_res", sres}, {"energy", o.energy}, {"brdf", brdf}};
  if (two) {
    material["normals_res"] = nres;
    params["normals_res"] = nres;
  }
  nlohmann::json meta = {
      {"arrays", {spec.ToJson()}},
      {"basis",
       {{"rows",
         two ? nlohmann::json{{"kind", "direction-pairs"}, {"normals_res", nres}, {"samples_res", sres}, {"role", role}}
             : nlohmann::json{{"kind", "cubemap"}, {"cube_res", sres}, {"basis", "pixel"}, {"role", role}}},
        {"cols", {{"kind", "cubemap"}, {"cube_res", res}, {"basis", "haar-squares"}}}}},
      {"material", material},
      {"provenance", {{"tool", std::string("ltbake ") + kToolVersion}, {"stage", "material"}, {"parameters", params}}},
  };
  io::WriterOptions wo;
  wo.overwrite_mismatch = o.overwrite;
  LTB_ASSIGN_OR_RETURN(io::ContainerWriter writer, io::ContainerWriter::Open(o.output, meta, wo));
  MaterialResult result;
  result.rows = rows;
  result.cols = cols;
  result.samples_res = sres;
  result.normals_res = nres;
  result.chunks_already_committed = writer.resume_info().committed_chunks;
  const std::vector<uint64_t> missing = writer.Missing(0);
  std::mutex mu;
  format::EncodeOptions eo;
  eo.sparse = true;
  eo.zstd = true;
  eo.dtype = format::DType::kF32;
  const uint32_t sr = static_cast<uint32_t>(sres);
  const TexelTable texels(res);
  LTB_RETURN_IF_ERROR(
      stages::ParallelFor(missing, std::max(1, o.jobs), progress, "chunks", [&](uint64_t chunk) -> Status {
        const format::ChunkExtent e = spec.Extent(chunk);
        std::vector<float> values(e.rows * cols);
        uint64_t kept = 0;
        double worst = 1;
        for (uint64_t r = 0; r < e.rows; ++r) {
          const uint64_t row = e.row0 + r;
          const glm::dvec3 wr = cubemap::TexelCenter(cubemap::ColumnToTexel(row % per_normal, sr), sr);
          const glm::dvec3 n =
              two ? cubemap::TexelCenter(cubemap::ColumnToTexel(row / per_normal, static_cast<uint32_t>(nres)),
                                         static_cast<uint32_t>(nres))
                  : wr;
          worst = std::min(worst, MaterialRow(o.brdf, n, wr, texels, o.energy, values.data() + r * cols, &kept));
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
