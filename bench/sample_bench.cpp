// Sample-stage throughput: rays/s of the whole stage (RunSample: ray generation, Embree,
// transport bookkeeping, encoding, writing) beside a bare Embree loop tracing exactly the
// same rays in the same batches with the same Embree call (TraceBare: only rtcOccludedNp is timed).
// ratio = stage rays/s (wall) / bare rays/s; cpu_ratio = bare Embree thread-seconds /
// stage CPU seconds (user + sys), which a slow disk or a busy machine distorts less.
// usage: ltb_sample_bench SCENE.toml OUT_DIR [--cube-res R] [--spp N] [--jobs J] [--reps K]
#include <sys/resource.h>

#include <algorithm>
#include <cstdio>
#include <cstdlib>
#include <filesystem>
#include <string>
#include <vector>

#include "stages/sample/sample.h"

static double CpuSeconds() {
  rusage u;
  getrusage(RUSAGE_SELF, &u);
  return u.ru_utime.tv_sec + u.ru_utime.tv_usec * 1e-6 + u.ru_stime.tv_sec + u.ru_stime.tv_usec * 1e-6;
}

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr, "usage: %s SCENE.toml OUT_DIR [--cube-res R] [--spp N] [--jobs J] [--reps K]\n", argv[0]);
    return 2;
  }
  ltb::stages::SampleOptions o;
  o.scene = argv[1];
  std::string dir = argv[2];
  int reps = 3;
  for (int i = 3; i + 1 < argc; i += 2) {
    std::string k = argv[i];
    if (k == "--cube-res")
      o.cube_res = static_cast<uint32_t>(std::atoi(argv[i + 1]));
    else if (k == "--spp")
      o.spp = static_cast<uint32_t>(std::atoi(argv[i + 1]));
    else if (k == "--jobs")
      o.jobs = std::atoi(argv[i + 1]);
    else if (k == "--reps")
      reps = std::atoi(argv[i + 1]);
  }
  o.output = (std::filesystem::path(dir) / "sample-bench.ltm").string();
  for (int rep = 0; rep < reps; ++rep) {
    std::filesystem::remove(o.output);
    double cpu0 = CpuSeconds();
    auto stage = ltb::stages::RunSample(o, {});
    double stage_cpu = CpuSeconds() - cpu0;
    if (!stage.ok()) {
      std::fprintf(stderr, "%s\n", stage.status().message().c_str());
      return 1;
    }
    auto bare = ltb::stages::TraceBare(o);
    if (!bare.ok()) {
      std::fprintf(stderr, "%s\n", bare.status().message().c_str());
      return 1;
    }
    double stage_rate = stage->rays / stage->seconds;
    // Bare rate with the same number of threads busy: rays per second of Embree time per thread.
    double bare_rate = bare->rays / (bare->trace_thread_seconds / o.jobs);
    std::printf(
        "{\"rep\":%d,\"cube_res\":%u,\"spp\":%u,\"jobs\":%d,\"stage_rays\":%llu,\"stage_seconds\":%.3f,"
        "\"stage_rays_per_s\":%.4g,\"bare_rays\":%llu,\"bare_embree_thread_seconds\":%.3f,"
        "\"bare_rays_per_s\":%.4g,\"ratio\":%.3f,\"stage_cpu_seconds\":%.3f,"
        "\"cpu_ratio\":%.3f}\n",
        rep, stage->cube_res, stage->spp, o.jobs, static_cast<unsigned long long>(stage->rays), stage->seconds,
        stage_rate, static_cast<unsigned long long>(bare->rays), bare->trace_thread_seconds, bare_rate,
        stage_rate / bare_rate, stage_cpu, bare->trace_thread_seconds / stage_cpu);
    std::fflush(stdout);
  }
  std::filesystem::remove(o.output);
  return 0;
}
