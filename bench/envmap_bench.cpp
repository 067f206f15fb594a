// The per-frame environment resampler (stages/images/resampler.h): Create and Resample times
// at R = 32, a 2048 × 1024 synthetic lat-long map first, then each map given. Medians of
// `--repeats` runs (default 5), each of 200 rotations; the machine is shared, so compare
// maps within one run.
//
//   build/bench/ltb_envmap_bench [--repeats N] [MAP.exr ...]   (make bench-build first)
#include <algorithm>
#include <chrono>
#include <cstdio>
#include <cstdlib>
#include <cstring>
#include <random>
#include <string>
#include <vector>

#include "stages/images/envmap.h"
#include "stages/images/resampler.h"

namespace {

using namespace ltb::stages;

double Seconds(std::chrono::steady_clock::time_point since) {
  return std::chrono::duration<double>(std::chrono::steady_clock::now() - since).count();
}

double Median(std::vector<double> v) {
  std::sort(v.begin(), v.end());
  return v[v.size() / 2];
}

int Time(const EnvMap& env, const std::string& what, int repeats) {
  const uint64_t r = 32;
  const int frames = 200;
  std::vector<double> create, frame;
  uint64_t ww = 0, rows = 0, pieces = 0;
  std::vector<float> out(6 * r * r * 3);
  for (int k = 0; k < repeats; ++k) {
    auto t0 = std::chrono::steady_clock::now();
    auto rs = CubemapResampler::Create(env, r);
    create.push_back(Seconds(t0));
    if (!rs.ok()) {
      std::fprintf(stderr, "%s: %s\n", what.c_str(), rs.status().ToString().c_str());
      return 1;
    }
    ww = rs->working_width(), rows = rs->working_rows(), pieces = rs->pieces();
    t0 = std::chrono::steady_clock::now();
    for (int i = 0; i < frames; ++i) rs->Resample(2 * 3.141592653589793 * i / frames, out.data());
    frame.push_back(Seconds(t0) / frames);
  }
  std::printf(
      "%s %llux%llu -> R=%llu: Create %.1f ms, Resample %.3f ms/frame (working grid %llux%llu, %llu edge "
      "pieces; medians of %d)\n",
      what.c_str(), (unsigned long long)env.width, (unsigned long long)env.height, (unsigned long long)r,
      Median(create) * 1e3, Median(frame) * 1e3, (unsigned long long)ww, (unsigned long long)rows,
      (unsigned long long)pieces, repeats);
  return 0;
}

}  // namespace

int main(int argc, char** argv) {
  int repeats = 5;
  std::vector<std::string> maps;
  for (int i = 1; i < argc; ++i) {
    if (std::strcmp(argv[i], "--repeats") == 0 && i + 1 < argc) {
      repeats = std::max(1, std::atoi(argv[++i]));
    } else {
      maps.push_back(argv[i]);
    }
  }
  EnvMap env;
  env.width = 2048;
  env.height = 1024;
  env.path = "synthetic";
  env.rgb.resize(env.width * env.height * 3);
  std::mt19937 rng(2);
  std::uniform_real_distribution<float> dist(0.0f, 4.0f);
  for (float& v : env.rgb) v = dist(rng);
  int rc = Time(env, "synthetic", repeats);
  for (const std::string& m : maps) {
    EnvLoadOptions o;
    o.clamp = true;  // DWAB-compressed maps hold tiny negative values
    auto loaded = LoadEnvMap(m, o);
    if (!loaded.ok()) {
      std::fprintf(stderr, "%s\n", loaded.status().ToString().c_str());
      rc = 1;
      continue;
    }
    rc |= Time(*loaded, m, repeats);
  }
  return rc;
}
