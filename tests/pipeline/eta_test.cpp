// The whole-bake ETA's model (pipeline/eta.h): what it refuses to guess, its form (a + b·G per
// stage), its calibration by the steps already run, and the words it prints.
#include "pipeline/eta.h"

#include <gtest/gtest.h>

namespace ltb::pipeline {
namespace {

const EtaStep kTranspose{{"transpose"}, {{"zstd", false}}};
const EtaStep kQuantize{{"quantize"}, {{"error_ratio", 1.1}}};

TEST(BakeEta, NothingBeforeTheMatrixIsKnownOrForAStepItDoesNotModel) {
  BakeEta eta;
  EXPECT_FALSE(eta.Seconds({kTranspose}).has_value());
  eta.SetMatrixBytes(1'000'000'000);
  EXPECT_TRUE(eta.Seconds({kTranspose}).has_value());
  // Sampling's cost is the scene's (spp, bounces, geometry), not the matrix's.
  const EtaStep fused{{"sample", "row-transform"}, {{"sample", {{"spp", 4}}}, {"row-transform", {{"filter", "haar"}}}}};
  EXPECT_FALSE(eta.Seconds({kTranspose, fused}).has_value());
  EXPECT_FALSE(eta.Seconds({EtaStep{{"cpca"}, {}}}).has_value());
  EXPECT_TRUE(eta.Seconds({}).has_value());
  EXPECT_EQ(*eta.Seconds({}), 0.0);
}

TEST(BakeEta, EachStepIsAffineInTheMatrixSizeAndStepsAdd) {
  auto at = [](uint64_t bytes, const std::vector<EtaStep>& steps) {
    BakeEta eta;
    eta.SetMatrixBytes(bytes);
    return *eta.Seconds(steps);
  };
  for (const EtaStep& s : {kTranspose, kQuantize}) {
    const double g1 = at(1'000'000'000, {s}), g2 = at(2'000'000'000, {s}), g3 = at(3'000'000'000, {s});
    EXPECT_GT(g2, g1);
    EXPECT_NEAR(g3 - g2, g2 - g1, 1e-9 * g3) << s.stages[0];
  }
  EXPECT_NEAR(at(5'000'000'000, {kTranspose, kQuantize}),
              at(5'000'000'000, {kTranspose}) + at(5'000'000'000, {kQuantize}), 1e-9);
}

TEST(BakeEta, FinishedStepsScaleTheRestByHowFastTheyRan) {
  BakeEta eta;
  eta.SetMatrixBytes(1'600'000'000);
  const double model = *eta.Seconds({kQuantize});
  EXPECT_EQ(eta.speed_factor(), 1.0);
  eta.Finished(kTranspose, 2 * *eta.Seconds({kTranspose}));  // this machine: twice as slow
  EXPECT_NEAR(eta.speed_factor(), 2.0, 1e-12);
  EXPECT_NEAR(*eta.Seconds({kQuantize}), 2 * model, 1e-9);
  eta.Finished(EtaStep{{"sample"}, {}}, 100.0);  // not modelled: no calibration
  EXPECT_NEAR(eta.speed_factor(), 2.0, 1e-12);
}

TEST(BakeEta, TheColumnTransformsModeAndARelightsReferenceAreTold) {
  BakeEta eta;
  eta.SetMatrixBytes(1'600'000'000);
  auto column = [&](nlohmann::json p) { return *eta.Seconds({EtaStep{{"column-transform"}, std::move(p)}}); };
  // A rate-distortion budget over every column costs more than a per-column adaptive depth,
  // which costs more than one fixed depth (bench/results/eta_model.md measures all three).
  const double budget = column({{"depth", "adaptive"}, {"budget", "5%"}});
  const double adaptive = column({{"depth", "adaptive"}, {"keep", 0.05}});
  const double fixed = column({{"depth", "3"}, {"keep", 0.05}});
  EXPECT_GT(budget, adaptive);
  EXPECT_GT(adaptive, fixed);
  EXPECT_EQ(column({{"target_error", 0.01}}), column({{"budget", "1%"}}));
  const double with = *eta.Seconds({EtaStep{{"relight"}, {{"reference", true}}}});
  const double without = *eta.Seconds({EtaStep{{"relight"}, {{"reference", false}}}});
  EXPECT_GT(with, without);  // the reference is relit exactly, streamed
}

TEST(BakeEta, ApproxDurationRoundsToWhatAPersonReads) {
  EXPECT_EQ(ApproxDuration(0.2), "about 1 s");
  EXPECT_EQ(ApproxDuration(25.4), "about 25 s");
  EXPECT_EQ(ApproxDuration(150), "about 3 min");
  EXPECT_EQ(ApproxDuration(7200), "about 2.0 h");
}

}  // namespace
}  // namespace ltb::pipeline
