// .npy header codec against headers as NumPy writes them (format 1.0 and 2.0).
#include "format/npy.h"

#include <gtest/gtest.h>

#include <cstring>

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
  EXPECT_FALSE(
      format::ParseNpyHeader(Npy("{'descr': '<f4', 'fortran_order': False, 'shape': (99999999999999999999999, 2), }"))
          .ok());
  std::vector<std::byte> shortb(5);
  EXPECT_FALSE(format::ParseNpyHeader(shortb).ok());
}

// Hostile headers: the header is parsed as the Python literal NumPy reads, not searched.
TEST(Npy, DecoyKeysInsideStringsAreNotKeys) {
  // 'shape' inside the descr string: descr is that whole string (NumPy refuses the dtype).
  auto h =
      format::ParseNpyHeader(Npy("{'descr': \"<f4 'shape': (1, 16)\", 'fortran_order': False, 'shape': (4, 4), }"));
  ASSERT_TRUE(h.ok()) << h.status().message();
  EXPECT_EQ(h->descr, "<f4 'shape': (1, 16)");
  EXPECT_EQ(h->shape, (std::vector<uint64_t>{4, 4}));
  EXPECT_EQ(h->itemsize, 0u);
  // ... inside another key's string: the extra key is refused, by name.
  auto x = format::ParseNpyHeader(
      Npy("{'descr': '<f4', 'x': \"'shape': (1, 16)\", 'fortran_order': False, 'shape': (4, 4), }"));
  ASSERT_FALSE(x.ok());
  EXPECT_NE(x.status().message().find("'x'"), std::string::npos) << x.status().message();
  // A key given twice (NumPy keeps the last one silently).
  auto twice =
      format::ParseNpyHeader(Npy("{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), 'shape': (1, 16)}"));
  ASSERT_FALSE(twice.ok());
  EXPECT_NE(twice.status().message().find("twice"), std::string::npos) << twice.status().message();
}

TEST(Npy, ReadsPythonLiteralSyntaxAsNumpyDoes) {
  struct Case {
    std::string text;
    std::vector<uint64_t> shape;
    std::string descr;
    int major;
  };
  const std::vector<Case> cases = {
      {R"({"descr": "<f4", "fortran_order": False, "shape": (3, 4)})", {3, 4}, "<f4", 1},
      {R"({'shape': (3, 4), 'fortran_order': False, 'descr': '<f8'})", {3, 4}, "<f8", 1},
      {R"({'descr': '<' 'f4', 'fortran_order': False, 'shape': ((3), 4,), })", {3, 4}, "<f4", 1},
      {R"({'descr': '\x3cf4', 'fortran_order': False, 'shape': (0x3, 0o4), })", {3, 4}, "<f4", 1},
      {"{'descr': u'<f4', # comment\n 'fortran_order': False,\n 'shape': (3L, 4L), }", {3, 4}, "<f4", 2},
      {R"({'descr': '''<f4''', 'fortran_order': False, 'shape': (1_000, +4), })", {1000, 4}, "<f4", 3},
      {R"({'descr': '<f4', 'fortran_order': False, 'shape': (), })", {}, "<f4", 1},
      {"{'descr': '<f4', 'fortran_order': False, 'shape': (7,), } \\\n", {7}, "<f4", 1},
      {R"({'descr': [('a', '<f4'), ('b', '<i2', (2,))], 'fortran_order': False, 'shape': (5,), })",
       {5},
       "[('a', '<f4'), ('b', '<i2', (2,))]",
       1},
  };
  for (const Case& c : cases) {
    auto h = format::ParseNpyHeader(Npy(c.text, c.major));
    ASSERT_TRUE(h.ok()) << c.text << ": " << h.status().message();
    EXPECT_EQ(h->shape, c.shape) << c.text;
    EXPECT_EQ(h->descr, c.descr) << c.text;
  }
}

TEST(Npy, RefusesWhatNumpyRefuses) {
  for (const char* text : {
           "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), 'extra': 0}",
           "{'descr': '<f4', 'fortran_order': 0, 'shape': (4, 4), }",
           "{'descr': '<f4', 'fortran_order': False, 'shape': [4, 4], }",
           "{'descr': '<f4', 'fortran_order': False, 'shape': (4), }",
           "{'descr': '<f4', 'fortran_order': False, 'shape': (4, '4'), }",
           "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4.0), }",
           "{'descr': '<f4', 'fortran_order': False, 'shape': (4, --4), }",
           "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 04), }",
           "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4_), }",
           "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4),, }",
           "{'descr': '<f4', 'fortran_order': False, 'shape': (4 4), }",
           "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), }}",
           "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), ",
           "{'descr': f'<f4', 'fortran_order': False, 'shape': (4, 4), }",
           "{'descr': b'<f4' '<', 'fortran_order': False, 'shape': (4, 4), }",
           "{b'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), }",
           "{'descr': '<f4', 'fortran_order': False, 'shape': (4, 4), 3: 4}",
           "{'descr': None, 'fortran_order': False, 'shape': (4, 4), }",
           "{'descr': '<f4', 'fortran_order': false, 'shape': (4, 4), }",
           "['descr', '<f4']",
           "",
       }) {
    auto h = format::ParseNpyHeader(Npy(text));
    EXPECT_FALSE(h.ok()) << "accepted: " << text;
  }
  // The 'L' suffix of Python 2 is a 1.0/2.0 thing.
  EXPECT_FALSE(format::ParseNpyHeader(Npy("{'descr': '<f4', 'fortran_order': False, 'shape': (4L,), }", 3)).ok());
  // NUL bytes, deep nesting, minor versions, version 4.
  const std::string nul("{'descr': '<f4', 'fortran_order': False, 'shape': (4,)}\0", 57);
  EXPECT_FALSE(format::ParseNpyHeader(Npy(nul)).ok());
  const std::string deep =
      "{'descr': '<f4', 'fortran_order': False, 'shape': " + std::string(100, '(') + "4," + std::string(100, ')') + "}";
  EXPECT_FALSE(format::ParseNpyHeader(Npy(deep)).ok());
  auto minor = Npy("{'descr': '<f4', 'fortran_order': False, 'shape': (4,)}");
  minor[7] = std::byte{1};
  EXPECT_FALSE(format::ParseNpyHeader(minor).ok());
  auto v4 = Npy("{'descr': '<f4', 'fortran_order': False, 'shape': (4,)}");
  v4[6] = std::byte{4};
  EXPECT_FALSE(format::ParseNpyHeader(v4).ok());
  // Format 3.0 headers are UTF-8.
  EXPECT_FALSE(format::ParseNpyHeader(Npy("{'descr': '<f4', 'fortran_order': False, 'shape': (4,)} \xff", 3)).ok());
  EXPECT_TRUE(
      format::ParseNpyHeader(Npy("{'descr': '<f4', 'fortran_order': False, 'shape': (4,)} # \xc3\xa9", 3)).ok());
}

TEST(Npy, DataBytesAreCheckedForOverflow) {
  auto h = format::ParseNpyHeader(
      Npy("{'descr': '<f4', 'fortran_order': False, 'shape': (1099511627776, 1099511627776), }"));
  ASSERT_TRUE(h.ok());
  auto bytes = format::NpyDataBytes(*h);
  ASSERT_FALSE(bytes.ok());  // 2^82 bytes: used to be reported as "needs 0 bytes"
  EXPECT_NE(bytes.status().message().find("(1099511627776, 1099511627776)"), std::string::npos);
  EXPECT_NE(bytes.status().message().find("2^64"), std::string::npos);
  h = format::ParseNpyHeader(Npy("{'descr': '<f8', 'fortran_order': False, 'shape': (3, 5, 7), }"));
  ASSERT_TRUE(h.ok());
  ASSERT_TRUE(format::NpyDataBytes(*h).ok());
  EXPECT_EQ(*format::NpyDataBytes(*h), 3u * 5 * 7 * 8);
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
