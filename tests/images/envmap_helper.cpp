// Test helper for envmap_oracle_test.py: `ltb_envmap_helper ENV OUT.npy R ROTATION` writes the
// cubemap of ENV rotated by ROTATION radians about +Z as a 6R² × 3 float32 .npy and prints
// the source power per channel.
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <vector>

#include "format/npy.h"
#include "stages/images/envmap.h"

int main(int argc, char** argv) {
  if (argc != 5) {
    std::fprintf(stderr, "usage: %s ENV OUT.npy R ROTATION\n", argv[0]);
    return 2;
  }
  const uint64_t r = std::strtoull(argv[3], nullptr, 10);
  auto env = ltb::stages::LoadEnvMap(argv[1], {});
  if (!env.ok()) {
    std::fprintf(stderr, "%s\n", env.status().ToString().c_str());
    return 1;
  }
  auto rs = ltb::stages::CubemapResampler::Create(*env, r);
  if (!rs.ok()) {
    std::fprintf(stderr, "%s\n", rs.status().ToString().c_str());
    return 1;
  }
  std::vector<float> out(6 * r * r * 3);
  rs->Resample(std::strtod(argv[4], nullptr), out.data());
  std::vector<std::byte> header = ltb::format::EncodeNpyHeader("<f4", {6 * r * r, 3});
  std::ofstream f(argv[2], std::ios::binary);
  f.write(reinterpret_cast<const char*>(header.data()), header.size());
  f.write(reinterpret_cast<const char*>(out.data()), out.size() * sizeof(float));
  std::printf("%.17g %.17g %.17g\n", rs->SourcePower(0), rs->SourcePower(1), rs->SourcePower(2));
  return f ? 0 : 1;
}
