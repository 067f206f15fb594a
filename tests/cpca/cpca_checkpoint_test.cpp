// The cpca checkpoint file: round trip, and every damaged form refused (never read as a
// model) with a message naming the file.
#include "stages/cpca/cpca_checkpoint.h"

#include <gtest/gtest.h>

#include <cstdio>
#include <filesystem>
#include <fstream>
#include <iterator>

#include "stages/cpca/cpca.h"

namespace ltb::stages {
namespace {

std::string TempPath(const char* name) {
  return (std::filesystem::temp_directory_path() / (std::string("ltb_cpca_") + name)).string();
}

std::vector<char> Slurp(const std::string& p) {
  std::ifstream f(p, std::ios::binary);
  return {std::istreambuf_iterator<char>(f), {}};
}
void Spit(const std::string& p, const std::vector<char>& b) {
  std::ofstream f(p, std::ios::binary | std::ios::trunc);
  f.write(b.data(), static_cast<std::streamsize>(b.size()));
}

CpcaCheckpoint Sample() {
  CpcaCheckpoint cp;
  cp.header = {{"phase", "iterate"}, {"passes", 3}};
  for (int i = 0; i < 100; ++i) cp.values.push_back(i * 0.25 - 3);
  return cp;
}

TEST(CpcaCheckpoint, RoundTripsExactly) {
  const std::string p = TempPath("roundtrip");
  ASSERT_TRUE(WriteCpcaCheckpoint(p, Sample()).ok());
  auto r = ReadCpcaCheckpoint(p, 1000);
  ASSERT_TRUE(r.ok()) << r.status().message();
  ASSERT_TRUE(r->has_value());
  EXPECT_EQ((**r).header, Sample().header);
  EXPECT_EQ((**r).values, Sample().values);
  std::remove(p.c_str());
}

TEST(CpcaCheckpoint, AbsentFileIsNoCheckpoint) {
  auto r = ReadCpcaCheckpoint(TempPath("absent-never-written"), 1000);
  ASSERT_TRUE(r.ok());
  EXPECT_FALSE(r->has_value());
}

TEST(CpcaCheckpoint, RejectsEveryFlippedByte) {
  const std::string p = TempPath("flip");
  ASSERT_TRUE(WriteCpcaCheckpoint(p, Sample()).ok());
  const std::vector<char> good = Slurp(p);
  for (size_t i = 0; i < good.size(); ++i) {
    std::vector<char> bad = good;
    bad[i] ^= 0x20;
    Spit(p, bad);
    auto r = ReadCpcaCheckpoint(p, 1000);
    ASSERT_FALSE(r.ok()) << "flipped byte " << i << " was accepted";
    EXPECT_EQ(r.status().code(), StatusCode::kDataLoss);
    EXPECT_NE(r.status().message().find(p), std::string::npos) << r.status().message();
  }
  std::remove(p.c_str());
}

TEST(CpcaCheckpoint, RejectsEveryTruncation) {
  const std::string p = TempPath("trunc");
  ASSERT_TRUE(WriteCpcaCheckpoint(p, Sample()).ok());
  const std::vector<char> good = Slurp(p);
  for (size_t n = 0; n < good.size(); ++n) {
    Spit(p, std::vector<char>(good.begin(), good.begin() + n));
    auto r = ReadCpcaCheckpoint(p, 1000);
    EXPECT_FALSE(r.ok()) << "truncated to " << n << " bytes was accepted";
  }
  std::remove(p.c_str());
}

TEST(CpcaCheckpoint, RefusesMoreValuesThanTheCap) {
  const std::string p = TempPath("cap");
  ASSERT_TRUE(WriteCpcaCheckpoint(p, Sample()).ok());
  auto r = ReadCpcaCheckpoint(p, 10);
  EXPECT_FALSE(r.ok());
  std::remove(p.c_str());
}

TEST(Cpca, MissingInputNamesTheFile) {
  CpcaOptions o;
  o.input = TempPath("no-such-input.ltm");
  o.output = TempPath("no-such-output.ltm");
  auto r = RunCpca(o, Progress{});
  ASSERT_FALSE(r.ok());
  EXPECT_NE(r.status().message().find("no-such-input.ltm"), std::string::npos) << r.status().message();
}

TEST(Cpca, ZeroClustersRefused) {
  CpcaOptions o;
  o.clusters = 0;
  auto r = RunCpca(o, Progress{});
  ASSERT_FALSE(r.ok());
  EXPECT_EQ(r.status().code(), StatusCode::kInvalidArgument);
  EXPECT_NE(r.status().message().find("--clusters 0"), std::string::npos);
}

}  // namespace
}  // namespace ltb::stages
