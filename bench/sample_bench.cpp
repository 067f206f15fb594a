// Sample-stage throughput: rays/s of the whole stage (RunSample: ray generation, Embree,
// transport bookkeeping, encoding, writing) beside a bare Embree loop tracing exactly the
// same rays in the same batches with the same Embree call (TraceBare: only rtcOccludedNp is timed).
// ratio = stage rays/s (wall) / bare rays/s; cpu_ratio = bare Embree thread-seconds /
// stage CPU seconds (user + sys), which a slow disk or a busy machine distorts less.
// Repetitions interleave the two measurements and alternate which goes first (stage then
// bare, bare then stage), so drift in the machine's speed hits both alike; a last line
// gives the medians and ranges of both ratios.
// usage: ltb_sample_bench SCENE.toml OUT_DIR [--cube-res R] [--spp N] [--jobs J] [--reps K]
//                         [--no-direct-io] [--build LABEL]
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

static void MedianRange(std::vector<double> v, double* med, double* lo, double* hi) {
  std::sort(v.begin(), v.end());
  const size_t n = v.size();
  *med = n % 2 ? v[n / 2] : 0.5 * (v[n / 2 - 1] + v[n / 2]);
  *lo = v.front();
  *hi = v.back();
}

int main(int argc, char** argv) {
  if (argc < 3) {
    std::fprintf(stderr,
                 "usage: %s SCENE.toml OUT_DIR [--cube-res R] [--spp N] [--jobs J] [--reps K] [--no-direct-io] "
                 "[--build LABEL]\n",
                 argv[0]);
    return 2;
  }
  ltb::stages::SampleOptions o;
  o.scene = argv[1];
  std::string dir = argv[2], build = "";
  int reps = 3;
  for (int i = 3; i < argc; ++i) {
    std::string k = argv[i];
    if (k == "--no-direct-io") {
      o.direct_io = false;
      continue;
    }
    if (i + 1 >= argc) break;
    if (k == "--cube-res")
      o.cube_res = static_cast<uint32_t>(std::atoi(argv[++i]));
    else if (k == "--spp")
      o.spp = static_cast<uint32_t>(std::atoi(argv[++i]));
    else if (k == "--jobs")
      o.jobs = std::atoi(argv[++i]);
    else if (k == "--reps")
      reps = std::atoi(argv[++i]);
    else if (k == "--build")
      build = argv[++i];
  }
  o.output = (std::filesystem::path(dir) / "sample-bench.ltm").string();
  std::vector<double> ratios, cpu_ratios, cpu_cpu_ratios;
  for (int rep = 0; rep < reps; ++rep) {
    const bool bare_first = rep % 2 == 1;
    ltb::Result<ltb::stages::BareTraceResult> bare = ltb::Internal("not run");
    double bare_cpu = 0;
    auto run_bare = [&] {
      double c0 = CpuSeconds();
      bare = ltb::stages::TraceBare(o);
      bare_cpu = CpuSeconds() - c0;
    };
    if (bare_first) run_bare();
    std::filesystem::remove(o.output);
    double cpu0 = CpuSeconds();
    auto stage = ltb::stages::RunSample(o, {});
    double stage_cpu = CpuSeconds() - cpu0;
    if (!stage.ok()) {
      std::fprintf(stderr, "%s\n", stage.status().message().c_str());
      return 1;
    }
    if (!bare_first) run_bare();
    if (!bare.ok()) {
      std::fprintf(stderr, "%s\n", bare.status().message().c_str());
      return 1;
    }
    double stage_rate = stage->rays / stage->seconds;
    // Bare rate with the same number of threads busy: rays per second of Embree time per thread.
    double bare_rate = bare->rays / (bare->trace_thread_seconds / o.jobs);
    const double ratio = stage_rate / bare_rate, cpu_ratio = bare->trace_thread_seconds / stage_cpu;
    // The same with the Embree calls' CPU time (not their wall time) in the numerator:
    // the measure to trust when other processes take CPU time from the benchmark.
    const double cpu_ratio_cpu = bare->trace_cpu_seconds / stage_cpu;
    ratios.push_back(ratio);
    cpu_ratios.push_back(cpu_ratio);
    cpu_cpu_ratios.push_back(cpu_ratio_cpu);
    std::printf(
        "{\"build\":\"%s\",\"rep\":%d,\"order\":\"%s\",\"cube_res\":%u,\"spp\":%u,\"jobs\":%d,"
        "\"direct_io\":%s,\"stage_rays\":%llu,\"stage_seconds\":%.3f,"
        "\"stage_rays_per_s\":%.4g,\"bare_rays\":%llu,\"bare_embree_thread_seconds\":%.3f,"
        "\"bare_rays_per_s\":%.4g,\"ratio\":%.3f,\"stage_cpu_seconds\":%.3f,"
        "\"cpu_ratio\":%.3f,\"bare_embree_cpu_seconds\":%.3f,\"cpu_ratio_cpu\":%.3f,\"bare_wall_seconds\":%.3f,\"bare_"
        "cpu_seconds\":%.3f,\"bytes_direct\":%llu,"
        "\"write_queue_waits\":%llu}\n",
        build.c_str(), rep, bare_first ? "bare-stage" : "stage-bare", stage->cube_res, stage->spp, o.jobs,
        o.direct_io ? "true" : "false", static_cast<unsigned long long>(stage->rays), stage->seconds, stage_rate,
        static_cast<unsigned long long>(bare->rays), bare->trace_thread_seconds, bare_rate, ratio, stage_cpu, cpu_ratio,
        bare->trace_cpu_seconds, cpu_ratio_cpu, bare->wall_seconds, bare_cpu,
        static_cast<unsigned long long>(stage->bytes_direct),
        static_cast<unsigned long long>(stage->write_queue_waits));
    std::fflush(stdout);
  }
  std::filesystem::remove(o.output);
  if (reps > 1) {
    double m, lo, hi, cm, clo, chi, pm, plo, phi;
    MedianRange(ratios, &m, &lo, &hi);
    MedianRange(cpu_ratios, &cm, &clo, &chi);
    MedianRange(cpu_cpu_ratios, &pm, &plo, &phi);
    std::printf(
        "{\"build\":\"%s\",\"summary\":true,\"reps\":%d,\"cube_res\":%u,\"ratio_median\":%.3f,"
        "\"ratio_min\":%.3f,\"ratio_max\":%.3f,\"cpu_ratio_median\":%.3f,\"cpu_ratio_min\":%.3f,"
        "\"cpu_ratio_max\":%.3f,\"cpu_ratio_cpu_median\":%.3f,\"cpu_ratio_cpu_min\":%.3f,"
        "\"cpu_ratio_cpu_max\":%.3f}\n",
        build.c_str(), reps, o.cube_res.value_or(0), m, lo, hi, cm, clo, chi, pm, plo, phi);
  }
  return 0;
}
