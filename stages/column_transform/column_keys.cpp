// The selection keys of ColumnCompressor (column_compressor.h): per lane and pixel the bits of
// |coefficient| × its root weight, their histogram and the exact-zero statistics of the
// region an incremental update changes. Kept up to date as the depth changes, for one lane
// or for several in one pass over the coefficients. The hottest loops of the 4D search.
#include <algorithm>
#include <cmath>
#include <cstring>

#include "stages/column_transform/column_compressor.h"

namespace ltb::stages {

void ColumnCompressor::UpdateKeys(size_t lane, int depth) {
  uint32_t* keys = keys_.data() + lane * pixels_;
  uint32_t* hist = key_hist_.data() + lane * kKeyBins;
  uint64_t& zeros = key_zeros_[lane];
  const float* rw = !orthonormal_ && depth > 0 ? root_weights_.data() + depth * pixels_ : nullptr;
  if (key_depth_[lane] == depth) return;
  auto key = [&](uint64_t p) {
    float k = std::fabs(coeffs_[p * kLanes + lane]);
    if (rw) k *= rw[p];
    uint32_t bits;
    std::memcpy(&bits, &k, 4);
    return bits;
  };
  if (depth > 0 && key_depth_[lane] == depth - 1) {
    // Only the previous low band changed (and, biorthogonal, its weights).
    const auto& band = bands_[depth - 1];
    for (uint64_t y = 0; y < band.height; ++y)
      for (uint64_t x = 0; x < band.width; ++x) {
        uint64_t p = y * width_ + x;
        hist[keys[p] >> kKeyShift]--;
        zeros -= keys[p] == 0;
        keys[p] = key(p);
        hist[keys[p] >> kKeyShift]++;
        zeros += keys[p] == 0;
      }
  } else {
    std::fill(hist, hist + kKeyBins, 0u);
    zeros = 0;
    for (uint64_t p = 0; p < pixels_; ++p) {
      keys[p] = key(p);
      hist[keys[p] >> kKeyShift]++;
      zeros += keys[p] == 0;
    }
  }
  key_depth_[lane] = depth;
}

void ColumnCompressor::UpdateKeysGroup(int depth, const bool* lanes) {
  // UpdateKeys for several lanes in one pass over the coefficients ([pixel][lane]): the
  // keys of a pixel's eight lanes are computed together, then each lane's histogram.
  const float* rw = !orthonormal_ && depth > 0 ? root_weights_.data() + depth * pixels_ : nullptr;
  for (int incremental = 1; incremental >= 0; --incremental) {
    size_t lane[kLanes], m = 0;
    for (size_t k = 0; k < kLanes; ++k) {
      if (!lanes[k] || key_depth_[k] == depth) continue;
      // From depth 0 the whole image changes: a rebuild is cheaper than an update.
      const bool inc = depth > 1 && key_depth_[k] == depth - 1;
      if (inc == (incremental == 1)) lane[m++] = k;
    }
    if (m == 0) continue;
    const uint64_t rw_w = incremental ? bands_[depth - 1].width : width_;
    const uint64_t rw_h = incremental ? bands_[depth - 1].height : height_;
    const uint64_t sub_w = bands_[depth].width, sub_h = bands_[depth].height;  // the next region
    for (size_t i = 0; i < m; ++i) {
      region_[lane[i]].now = region_[lane[i]].next = RegionStats{};
      if (!incremental) {
        std::fill(key_hist_.begin() + lane[i] * kKeyBins, key_hist_.begin() + (lane[i] + 1) * kKeyBins, 0u);
        key_zeros_[lane[i]] = 0;
      }
    }
    if (incremental) {
      UpdateKeyLanes(depth, lane, m, rw, rw_w, rw_h, sub_w, sub_h);
    } else {
      RebuildKeyLanes(depth, lane, m, rw, sub_w, sub_h);
    }
  }
}

// The keys of lanes lane[0..m) rebuilt from the coefficients (or, at depth 0, the pixels),
// then each lane's histogram over its contiguous keys, then the next region's statistics
// (only an update from depth >= 1 uses them).
void ColumnCompressor::RebuildKeyLanes(int depth, const size_t* lane, size_t m, const float* rw, uint64_t sub_w,
                                       uint64_t sub_h) {
  if (depth == 0 && columns_) {  // the pixels: each lane's key is |x|, read contiguously
    for (size_t i = 0; i < m; ++i) {
      uint32_t* keys = keys_.data() + lane[i] * pixels_;
      std::memcpy(keys, columns_[lane[i]], pixels_ * 4);
      for (uint64_t p = 0; p < pixels_; ++p) keys[p] &= 0x7fffffffu;
    }
  }
  for (uint64_t p = 0; p < pixels_ && !(depth == 0 && columns_); ++p) {
    alignas(32) float a[kLanes];
    const float* c = coeffs_.data() + p * kLanes;
    for (size_t k = 0; k < kLanes; ++k) a[k] = std::fabs(c[k]);
    if (rw)
      for (size_t k = 0; k < kLanes; ++k) a[k] *= rw[p];
    uint32_t bits[kLanes];
    std::memcpy(bits, a, sizeof(bits));
    for (size_t i = 0; i < m; ++i) keys_[lane[i] * pixels_ + p] = bits[lane[i]];
  }
  for (size_t i = 0; i < m; ++i) {
    const size_t k = lane[i];
    const uint32_t* keys = keys_.data() + k * pixels_;
    uint32_t* hist = key_hist_.data() + k * kKeyBins;
    // Four histograms, summed: neighbouring keys often share a bin, and one counter
    // incremented back to back waits on its own store.
    std::fill(sub_hist_.begin(), sub_hist_.end(), 0u);
    uint32_t* h0 = sub_hist_.data();
    uint32_t* h1 = h0 + kKeyBins;
    uint32_t* h2 = h1 + kKeyBins;
    uint32_t* h3 = h2 + kKeyBins;
    uint64_t zeros = 0, p = 0;
    for (; p + 4 <= pixels_; p += 4) {
      h0[keys[p] >> kKeyShift]++;
      h1[keys[p + 1] >> kKeyShift]++;
      h2[keys[p + 2] >> kKeyShift]++;
      h3[keys[p + 3] >> kKeyShift]++;
      zeros += (keys[p] == 0) + (keys[p + 1] == 0) + (keys[p + 2] == 0) + (keys[p + 3] == 0);
    }
    for (; p < pixels_; ++p) {
      h0[keys[p] >> kKeyShift]++;
      zeros += keys[p] == 0;
    }
    for (size_t b = 0; b < kKeyBins; ++b) hist[b] = h0[b] + h1[b] + h2[b] + h3[b];
    key_zeros_[k] = zeros;
    RegionTrack& r = region_[k];
    if (depth > 0) {
      for (uint64_t y = 0; y < sub_h; ++y)
        for (uint64_t x = 0; x < sub_w; ++x) {
          const uint64_t p = y * width_ + x;
          r.next.Add(coeffs_[p * kLanes + k] == 0.0f ? 0u : 1u, keys[p]);
        }
    }
    r.before = RegionStats{0, 0};  // unknown
    r.saved = r.next;
    key_depth_[k] = depth;
  }
}

// The keys of lanes lane[0..m) updated where the previous low band (rw_w × rw_h) changed,
// with their histograms and region statistics, in one pass over the coefficients.
void ColumnCompressor::UpdateKeyLanes(int depth, const size_t* lane, size_t m, const float* rw, uint64_t rw_w,
                                      uint64_t rw_h, uint64_t sub_w, uint64_t sub_h) {
  // Locals, so that the histogram stores do not make the compiler reload members.
  uint32_t* keys_of[kLanes];
  uint32_t* hist_of[kLanes];
  uint64_t zeros_of[kLanes];
  RegionStats now_of[kLanes], next_of[kLanes];
  for (size_t i = 0; i < m; ++i) {
    keys_of[i] = keys_.data() + lane[i] * pixels_;
    hist_of[i] = key_hist_.data() + lane[i] * kKeyBins;
    zeros_of[i] = key_zeros_[lane[i]];
  }
  const float* coeffs = coeffs_.data();
  const uint64_t width = width_;
  for (uint64_t y = 0; y < rw_h; ++y)
    for (uint64_t x = 0; x < rw_w; ++x) {
      const uint64_t p = y * width + x;
      alignas(32) float a[kLanes];
      const float* c = coeffs + p * kLanes;
      const float r = rw ? rw[p] : 1.0f;
      for (size_t k = 0; k < kLanes; ++k) a[k] = std::fabs(c[k]);
      uint32_t abs_bits[kLanes], bits[kLanes];
      std::memcpy(abs_bits, a, sizeof(abs_bits));
      if (rw)
        for (size_t k = 0; k < kLanes; ++k) a[k] *= r;
      std::memcpy(bits, a, sizeof(bits));
      const bool sub = x < sub_w && y < sub_h;
      for (size_t i = 0; i < m; ++i) {
        const size_t k = lane[i];
        uint32_t* keys = keys_of[i];
        uint32_t* hist = hist_of[i];
        const uint32_t old_key = keys[p];
        hist[old_key >> kKeyShift]--;
        zeros_of[i] += (bits[k] == 0) - static_cast<uint64_t>(old_key == 0);
        now_of[i].Add(abs_bits[k], bits[k]);
        if (sub) next_of[i].Add(abs_bits[k], bits[k]);
        keys[p] = bits[k];
        hist[bits[k] >> kKeyShift]++;
      }
    }
  for (size_t i = 0; i < m; ++i) {
    RegionTrack& r = region_[lane[i]];
    key_zeros_[lane[i]] = zeros_of[i];
    r.now = now_of[i];
    r.before = r.saved;
    r.saved = next_of[i];
    key_depth_[lane[i]] = depth;
  }
}

}  // namespace ltb::stages
