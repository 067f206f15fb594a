// .npy header codec against headers as NumPy writes them (format 1.0 and 2.0).
#include <gtest/gtest.h>

#include <cstring>

#include "format/npy.h"

namespace ltb {
namespace {

std::vector<std::byte> Npy(const std::string& dict, int major = 1) {
  std::vector<std::byte> b(major == 1 ? 10 : 12);
  std::memcpy(b.data(), "\x93NUMPY", 6);
  b[6] = std::byte(major);
  std::string text = dict + "\n";
  if (major == 1) {
    uint16_t n = static_cast<uint16_t>(text.size());
    std::memcpy(&b[8], &n, 2);
  } else {
    uint32_t n = static_cast<uint32_t>(text.size());
    std::memcpy(&b[8], &n, 4);
  }
  for (char c : text) b.push_back(std::byte(c));
  return b;
}

TEST(Npy, ParsesNumpyHeader) {
  auto h = format::ParseNpyHeader(Npy("{'descr': '<f4', 'fortran_order': False, 'shape': (3, 40), }"));
  ASSERT_TRUE(h.ok()) << h.status().message();
  EXPECT_EQ(h->descr, "<f4");
  EXPECT_FALSE(h->fortran_order);
  EXPECT_EQ(h->shape, (std::vector<uint64_t>{3, 40}));
  EXPECT_EQ(h->itemsize, 4u);
}

TEST(Npy, ParsesVersion2AndF8AndOneDim) {
  auto h = format::ParseNpyHeader(Npy("{'descr': '<f8', 'fortran_order': True, 'shape': (7,), }", 2));
  ASSERT_TRUE(h.ok());
  EXPECT_EQ(h->itemsize, 8u);
  EXPECT_TRUE(h->fortran_order);
  EXPECT_EQ(h->shape, (std::vector<uint64_t>{7}));
}

TEST(Npy, UnsupportedDtypeHasNoItemsize) {
  auto h = format::ParseNpyHeader(Npy("{'descr': '>f4', 'fortran_order': False, 'shape': (2, 2), }"));
  ASSERT_TRUE(h.ok());
  EXPECT_EQ(h->itemsize, 0u);
}

TEST(Npy, RejectsGarbage) {
  EXPECT_FALSE(format::ParseNpyHeader(Npy("{'fortran_order': False, 'shape': (2, 2), }")).ok());
  EXPECT_FALSE(format::ParseNpyHeader(Npy("{'descr': '<f4', 'fortran_order': False, 'shape': (2, x), }")).ok());
  EXPECT_FALSE(format::ParseNpyHeader(Npy("{'descr': '<f4', 'fortran_order': False, 'shape': (99999999999999999999999, 2), }")).ok());
  std::vector<std::byte> shortb(5);
  EXPECT_FALSE(format::ParseNpyHeader(shortb).ok());
}

TEST(Npy, EncodedHeaderParsesBackAndIsAligned) {
  auto b = format::EncodeNpyHeader("<f4", {5, 6});
  EXPECT_EQ(b.size() % 64, 0u);
  auto h = format::ParseNpyHeader(b);
  ASSERT_TRUE(h.ok());
  EXPECT_EQ(h->shape, (std::vector<uint64_t>{5, 6}));
  EXPECT_EQ(h->data_offset, b.size());
}

}  // namespace
}  // namespace ltb
