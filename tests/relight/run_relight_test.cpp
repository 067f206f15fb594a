// RunRelight without the binary: a random transport matrix T (an 8 × 4 image, R = 2, pixel
// columns) written by RunConvert, a ready cubemap L as .npy; the relit image with every
// term is T·L computed here in double; with N terms it is T·L_N for the N brightest texels,
// and the report's share of the map's energy is theirs; a cancel between timing frames is
// a Cancelled status after the image is written; lighting near float32's largest value is
// relit exactly (at 2^-k) or refused.
#include "stages/relight/run_relight.h"

#include <gtest/gtest.h>
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <cstring>
#include <filesystem>
#include <fstream>
#include <numeric>
#include <random>
#include <string>
#include <vector>

#include "format/npy.h"
#include "stages/convert/convert.h"
#include "stages/row_transform/row_transform.h"

namespace ltb::stages {
namespace {

constexpr uint64_t kW = 8, kH = 4, kR = 2, kRows = kW * kH, kCols = 6 * kR * kR;

class RunRelightTest : public ::testing::Test {
 protected:
  void SetUp() override {
    dir_ = std::filesystem::path(::testing::TempDir()) / ("ltb_run_relight_" + std::to_string(::getpid()));
    std::filesystem::create_directories(dir_);
    std::mt19937 g(7);
    std::uniform_real_distribution<float> u(0.0f, 1.0f);
    T_.resize(kRows * kCols);
    for (float& v : T_) v = u(g);
    L_.resize(kCols * 3);
    for (float& v : L_) v = std::pow(u(g), 4.0f) * 5.0f;  // a few bright texels
    WriteNpy(Path("T.npy"), T_, kRows, kCols);
    WriteNpy(Path("L.npy"), L_, kCols, 3);
    ConvertOptions c;
    c.input = Path("T.npy");
    c.output = Path("raw.ltm");
    c.cube_res = kR;
    c.image_width = kW;
    c.image_height = kH;
    ASSERT_TRUE(RunConvert(c, Progress{}).ok());
  }
  void TearDown() override { std::filesystem::remove_all(dir_); }

  std::string Path(const std::string& name) const { return (dir_ / name).string(); }
  static void WriteNpy(const std::string& path, const std::vector<float>& v, uint64_t rows, uint64_t cols) {
    std::vector<std::byte> h = format::EncodeNpyHeader("<f4", {rows, cols});
    std::ofstream f(path, std::ios::binary);
    f.write(reinterpret_cast<const char*>(h.data()), static_cast<std::streamsize>(h.size()));
    f.write(reinterpret_cast<const char*>(v.data()), static_cast<std::streamsize>(v.size() * 4));
  }
  static std::vector<float> ReadNpy(const std::string& path, uint64_t count) {
    std::ifstream f(path, std::ios::binary);
    std::vector<char> all((std::istreambuf_iterator<char>(f)), {});
    std::vector<float> out(count);
    std::memcpy(out.data(), all.data() + all.size() - count * 4, count * 4);  // the data ends the file
    return out;
  }
  // T·L with the texels `keep` (all when empty), in double.
  std::vector<double> Product(const std::vector<bool>& keep) const {
    std::vector<double> b(kRows * 3, 0.0);
    for (uint64_t r = 0; r < kRows; ++r)
      for (uint64_t j = 0; j < kCols; ++j)
        if (keep.empty() || keep[j])
          for (int c = 0; c < 3; ++c) b[r * 3 + c] += double(T_[r * kCols + j]) * L_[j * 3 + c];
    return b;
  }
  RelightOptions Options(uint64_t terms) const {
    RelightOptions o;
    o.matrix = Path("raw.ltm");
    o.env = Path("L.npy");
    o.output = Path("out.npy");
    o.terms = terms;
    o.weighting = Weighting::kNone;
    o.jobs = 1;
    return o;
  }

  std::filesystem::path dir_;
  std::vector<float> T_, L_;
};

TEST_F(RunRelightTest, EveryTermIsTheMatrixTimesTheLighting) {
  auto r = RunRelight(Options(RelightOptions::kAllTerms), Progress{});
  ASSERT_TRUE(r.ok()) << r.status().message();
  std::vector<double> want = Product({});
  std::vector<float> got = ReadNpy(Path("out.npy"), kRows * 3);
  double scale = *std::max_element(want.begin(), want.end());
  for (size_t i = 0; i < want.size(); ++i) EXPECT_NEAR(got[i], want[i], 1e-5 * scale) << i;
  EXPECT_EQ(r->report["terms"], "all");
  EXPECT_EQ(r->report["terms_basis"], "pixels");
  EXPECT_EQ(r->report["terms_available"], kCols);
  EXPECT_NEAR(r->report["lighting_energy_kept"].get<double>(), 1.0, 1e-12);
}

TEST_F(RunRelightTest, NTermsAreTheBrightestTexels) {
  const uint64_t n = 5;
  auto r = RunRelight(Options(n), Progress{});
  ASSERT_TRUE(r.ok()) << r.status().message();
  // The n texels of largest |rgb| (weighting none), and their share of Σ rgb².
  std::vector<double> e(kCols);
  for (uint64_t j = 0; j < kCols; ++j)
    e[j] =
        double(L_[3 * j]) * L_[3 * j] + double(L_[3 * j + 1]) * L_[3 * j + 1] + double(L_[3 * j + 2]) * L_[3 * j + 2];
  std::vector<uint64_t> order(kCols);
  std::iota(order.begin(), order.end(), 0);
  std::sort(order.begin(), order.end(), [&](uint64_t a, uint64_t b) { return e[a] > e[b]; });
  std::vector<bool> keep(kCols, false);
  double kept = 0;
  for (uint64_t k = 0; k < n; ++k) keep[order[k]] = true, kept += e[order[k]];
  std::vector<double> want = Product(keep);
  std::vector<float> got = ReadNpy(Path("out.npy"), kRows * 3);
  double scale = *std::max_element(want.begin(), want.end());
  for (size_t i = 0; i < want.size(); ++i) EXPECT_NEAR(got[i], want[i], 1e-5 * scale) << i;
  EXPECT_EQ(r->report["terms_used"], n);
  EXPECT_NEAR(r->report["lighting_energy_kept"].get<double>(), kept / std::accumulate(e.begin(), e.end(), 0.0), 1e-6);
}

TEST_F(RunRelightTest, CancelBetweenFramesKeepsTheImage) {
  RelightOptions o = Options(10);
  o.frames = 3;
  Progress p;  // a signal that arrives once the image is on disk (a condition, not a time)
  const std::string out = Path("out.npy");
  p.cancelled = [out] { return std::filesystem::exists(out); };
  auto r = RunRelight(o, p);
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kCancelled);
  EXPECT_NE(r.status().message().find("after 0 of 3 timing frames"), std::string::npos) << r.status().message();
  EXPECT_TRUE(std::filesystem::exists(Path("out.npy")));
}

TEST_F(RunRelightTest, AReferenceOfAnotherShapeIsRefused) {
  RelightOptions o = Options(10);
  std::vector<float> other(kRows * 2 * kCols, 1.0f);
  WriteNpy(Path("other.npy"), other, kRows * 2, kCols);
  ConvertOptions c;
  c.input = Path("other.npy");
  c.output = Path("other.ltm");
  c.cube_res = kR;
  ASSERT_TRUE(RunConvert(c, Progress{}).ok());
  o.reference = Path("other.ltm");
  auto r = RunRelight(o, Progress{});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("is not the same bake"), std::string::npos) << r.status().message();
}

TEST_F(RunRelightTest, LightingNearFloat32sLargestValueRelightsExactlyOrIsRefused) {
  // Lighting near float32's largest value: its wavelet coefficients (a face's sum / R) and the
  // relighting's sums overflowed float32, and the image came out Inf or NaN with no error.
  // Relit at 2^-k and scaled back (a power of two is exact), the image of L·2^127 is the image
  // of L times 2^127, bit for bit, and so are the errors against a reference; an image beyond
  // float32 is an error naming the map, and nothing is written. A dim transport (T·2^-8) so
  // that the image of L·2^127 fits, through Haar rows (the lighting's wavelet transform).
  std::vector<float> dim = T_;
  for (float& v : dim) v = std::ldexp(v, -8);
  WriteNpy(Path("Td.npy"), dim, kRows, kCols);
  ConvertOptions c;
  c.input = Path("Td.npy");
  c.output = Path("raw_dim.ltm");
  c.cube_res = kR;
  c.image_width = kW;
  c.image_height = kH;
  ASSERT_TRUE(RunConvert(c, Progress{}).ok());
  RowTransformOptions rt;
  rt.input = Path("raw_dim.ltm");
  rt.output = Path("rows_dim.ltm");
  rt.jobs = 1;
  rt.direct_io = false;
  auto rows = RunRowTransform(rt, Progress{});
  ASSERT_TRUE(rows.ok()) << rows.status().message();
  // Every texel in [1, 2), and 2^127 times that: [1.7e38, 3.4e38), each face's Haar scaling
  // coefficient (sum / 2) beyond float32.
  std::mt19937 g(11);
  std::uniform_real_distribution<float> u(1.0f, 2.0f);
  std::vector<float> base(kCols * 3), big(kCols * 3);
  for (size_t i = 0; i < base.size(); ++i) base[i] = u(g), big[i] = std::ldexp(base[i], 127);
  WriteNpy(Path("Lbase.npy"), base, kCols, 3);
  WriteNpy(Path("Lbig.npy"), big, kCols, 3);

  RelightOptions o = Options(RelightOptions::kAllTerms);
  o.env = Path("Lbase.npy");
  o.matrix = Path("rows_dim.ltm");
  o.reference = Path("raw_dim.ltm");
  o.output = Path("small.npy");
  auto small = RunRelight(o, Progress{});
  ASSERT_TRUE(small.ok()) << small.status().message();
  o.env = Path("Lbig.npy");
  o.output = Path("big.npy");
  auto r = RunRelight(o, Progress{});
  ASSERT_TRUE(r.ok()) << r.status().message();
  const std::vector<float> a = ReadNpy(Path("small.npy"), kRows * 3), b = ReadNpy(Path("big.npy"), kRows * 3);
  for (size_t i = 0; i < a.size(); ++i) {
    ASSERT_TRUE(std::isfinite(b[i])) << i;
    EXPECT_EQ(b[i], std::ldexp(a[i], 127)) << i;
  }
  EXPECT_EQ(r->report["error"]["rel_l2"], small->report["error"]["rel_l2"]);
  EXPECT_LT(r->report["error"]["rel_l2"].get<double>(), 1e-6);

  // The full transport under them: T·L ≈ 24 · 0.5 · 1.5 · 2^127 per pixel, beyond float32.
  o = Options(RelightOptions::kAllTerms);
  o.env = Path("Lbig.npy");
  o.output = Path("over.npy");
  auto over = RunRelight(o, Progress{});
  ASSERT_FALSE(over.ok());
  EXPECT_NE(over.status().message().find("Lbig.npy is too bright to relight in float32"), std::string::npos)
      << over.status().message();
  EXPECT_NE(over.status().message().find("is inf, beyond float32's largest value"), std::string::npos)
      << over.status().message();
  EXPECT_FALSE(std::filesystem::exists(Path("over.npy")));
}

}  // namespace
}  // namespace ltb::stages
