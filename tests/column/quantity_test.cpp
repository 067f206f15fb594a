// stages/common/quantity: the one parser of sizes, fractions and budgets that every flag
// and recipe key uses. Expected values are the unit definitions (1 K = 1024 bytes, 1 KB =
// 1000 bytes, 8 bytes per nonzero of a size budget), written out.
#include "stages/common/quantity.h"

#include <gtest/gtest.h>

namespace ltb::stages {
namespace {

TEST(Quantity, ByteSizeUnitsArePowersOf1024Or1000AsWritten) {
  const std::pair<const char*, uint64_t> cases[] = {{"4096", 4096},
                                                    {"1B", 1},
                                                    {"64K", 65536},
                                                    {"64k", 65536},
                                                    {"64KiB", 65536},
                                                    {"64KB", 64000},
                                                    {"3M", 3u << 20},
                                                    {"3MiB", 3u << 20},
                                                    {"3MB", 3000000},
                                                    {"1.5G", uint64_t(3) << 29},
                                                    {"2GiB", uint64_t(2) << 30},
                                                    {"2GB", 2000000000},
                                                    {"1T", uint64_t(1) << 40},
                                                    {"1TB", 1000000000000}};
  for (const auto& [text, bytes] : cases) {
    auto r = ParseByteSize(text);
    ASSERT_TRUE(r.ok()) << text << ": " << r.status().message();
    EXPECT_EQ(*r, bytes) << text;
  }
}

TEST(Quantity, BadSizesNameTheText) {
  for (const char* text : {"", "0", "0.5", "K", "-1K", "+1K", "inf", "nan", "12Q", "1 K", "1KiBs", "1e30G"}) {
    auto r = ParseByteSize(text);
    ASSERT_FALSE(r.ok()) << text;
    EXPECT_NE(r.status().message().find(std::string("\"") + text + "\""), std::string::npos) << r.status().message();
  }
}

TEST(Quantity, DecimalsAreWholeFiniteDecimalTextInRange) {
  const std::pair<const char*, double> good[] = {{"0", 0.0},       {"-12.5", -12.5},  {"+3", 3.0},    {".5", 0.5},
                                                 {"5.", 5.0},      {"2.5e3", 2500.0}, {"1E-2", 0.01}, {"-1e+6", -1e6},
                                                 {"1000000", 1e6}, {"-0", 0.0}};
  for (const auto& [text, value] : good) {
    auto r = ParseDecimal(text, -1e6, 1e6);
    ASSERT_TRUE(r.ok()) << text << ": " << r.status().message();
    EXPECT_EQ(*r, value) << text;
  }
  // Not decimal text: strtod would take most of these (hexadecimal, inf, nan, leading space,
  // a prefix before a NUL or other bytes).
  const std::string nul("5\0abc", 5);
  for (const std::string& text : {std::string("nan"),
                                  std::string("NaN"),
                                  std::string("inf"),
                                  std::string("-inf"),
                                  std::string("infinity"),
                                  std::string("0x10"),
                                  std::string("0X1p3"),
                                  std::string(" 5"),
                                  std::string("5 "),
                                  std::string("5abc"),
                                  nul,
                                  std::string(""),
                                  std::string("."),
                                  std::string("-"),
                                  std::string("e5"),
                                  std::string("1e"),
                                  std::string("1e+"),
                                  std::string("1,5"),
                                  std::string("--1"),
                                  std::string("1.2.3")}) {
    auto r = ParseDecimal(text, -1e6, 1e6);
    ASSERT_FALSE(r.ok()) << text;
    EXPECT_NE(r.status().message().find("is not a decimal number"), std::string::npos) << r.status().message();
  }
  auto shown = ParseDecimal(nul, -1e6, 1e6);
  EXPECT_NE(shown.status().message().find("\"5\\x00abc\""), std::string::npos) << shown.status().message();
  // Decimal but out of range (1e999 overflows a double), with the range in the message.
  for (const char* text : {"1e20", "-1000000.5", "1e999", "-1e999"}) {
    auto r = ParseDecimal(text, -1e6, 1e6);
    ASSERT_FALSE(r.ok()) << text;
    EXPECT_EQ(r.status().message(), std::string("\"") + text + "\" is outside [-1e+06, 1e+06]");
  }
  EXPECT_FALSE(ParseDecimal("-0.5", 0, 1).ok());
  EXPECT_EQ(*ParseDecimal("1e-400", 0, 1), 0.0);  // underflows to zero: in range
}

TEST(Quantity, FractionsAsNumbersOrPercent) {
  EXPECT_DOUBLE_EQ(*ParseFraction("0.05"), 0.05);
  EXPECT_DOUBLE_EQ(*ParseFraction("5%"), 0.05);
  EXPECT_DOUBLE_EQ(*ParseFraction("100%"), 1.0);
  EXPECT_DOUBLE_EQ(*ParseFraction("1"), 1.0);
  for (const char* text : {"0", "0%", "1.01", "101%", "-0.5", "5 %", "5%%", "x", "", "nan", "0.05x"}) {
    EXPECT_FALSE(ParseFraction(text).ok()) << text;
  }
}

TEST(Quantity, BudgetKindsAndNonzeros) {
  // 1000 × 100 = 100,000 elements.
  auto nz = [](const char* text) {
    auto b = ParseBudget(text);
    EXPECT_TRUE(b.ok()) << text;
    return b.ok() ? BudgetNonzeros(*b, 1000, 100) : 0;
  };
  EXPECT_EQ(nz("0.02"), 2000u);  // a fraction (it has a point)
  EXPECT_EQ(nz("2%"), 2000u);
  EXPECT_EQ(nz("1e-2"), 1000u);    // an exponent makes it a fraction too
  EXPECT_EQ(nz("1500"), 1500u);    // a count
  EXPECT_EQ(nz("8K"), 1024u);      // 8192 bytes at 8 bytes per nonzero
  EXPECT_EQ(nz("8KB"), 1000u);     // 8000 bytes
  EXPECT_EQ(nz("1MiB"), 100000u);  // 131,072 nonzeros: at most every element
  EXPECT_EQ(nz("250000"), 100000u);
  for (const char* text : {"0", "1.5", "150%", "0%", "12Q", "", "-5", "inf", "2 %"}) {
    EXPECT_FALSE(ParseBudget(text).ok()) << text;
  }
}

}  // namespace
}  // namespace ltb::stages
