// Test helper: applies the 2D wavelet transform to raw little-endian arrays so Python
// can compare it with PyWavelets.
// usage: ltb_wavelet_helper forward|inverse FILTER DEPTH WIDTH HEIGHT LANES f32|f64 IN OUT
#include <cstdio>
#include <cstdlib>
#include <fstream>
#include <string>
#include <vector>

#include "stages/wavelet/wavelet.h"

template <typename T>
int Run(bool forward, ltb::wavelet::Filter f, int depth, size_t w, size_t h, size_t lanes, const char* in,
        const char* out) {
  std::vector<T> data(w * h * lanes), scratch(ltb::wavelet::ScratchSize(w, h, lanes));
  std::ifstream(in, std::ios::binary).read(reinterpret_cast<char*>(data.data()), data.size() * sizeof(T));
  if (forward)
    ltb::wavelet::Forward2D(f, data.data(), w, h, lanes, depth, scratch.data());
  else
    ltb::wavelet::Inverse2D(f, data.data(), w, h, lanes, depth, scratch.data());
  std::ofstream(out, std::ios::binary).write(reinterpret_cast<const char*>(data.data()), data.size() * sizeof(T));
  return 0;
}

int main(int argc, char** argv) {
  if (argc != 10) {
    std::fprintf(stderr, "usage: %s forward|inverse FILTER DEPTH W H LANES f32|f64 IN OUT\n", argv[0]);
    return 2;
  }
  auto f = ltb::wavelet::ParseFilter(argv[2]);
  if (!f.ok()) {
    std::fprintf(stderr, "%s\n", f.status().message().c_str());
    return 2;
  }
  bool forward = std::string(argv[1]) == "forward";
  int depth = std::atoi(argv[3]);
  size_t w = std::strtoull(argv[4], nullptr, 10), h = std::strtoull(argv[5], nullptr, 10),
         lanes = std::strtoull(argv[6], nullptr, 10);
  if (std::string(argv[7]) == "f64") return Run<double>(forward, *f, depth, w, h, lanes, argv[8], argv[9]);
  return Run<float>(forward, *f, depth, w, h, lanes, argv[8], argv[9]);
}
