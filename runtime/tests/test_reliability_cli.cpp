// Reliability of the `hrt` command line (docs/input-contract.md, "Runtime"):
// every malformed argument is one line on stderr and exit code 2, poses are
// bounded to the documented range, an unknown command is named, and no NaN
// or infinity reaches the JSON output. Runs the hrt binary as a child
// process on the golden pebble bundle (query against itself).
#include <unistd.h>

#include <algorithm>
#include <cmath>
#include <limits>

#include <gtest/gtest.h>
#include <nlohmann/json.hpp>

#include "../apps/finite_json.h"
#include "test_io_writer.h"

using namespace hrt_test;

namespace {

class HrtCli : public ::testing::Test {
 protected:
  void SetUp() override {
    // hrt is built with hrt_tests (one CMake project): a missing binary is a failure, not a skip.
    ASSERT_EQ(::access(hrt_binary().c_str(), X_OK), 0) << "hrt binary not built next to hrt_tests: " << hrt_binary();
    pebble_ = golden_dir() + "/pebble.hbundle";
  }
  // Exit 2 and exactly one line on stderr containing `fragment`.
  void expect_usage(const std::vector<std::string>& args, const std::string& fragment) {
    const HrtRun r = run_hrt(args, true);
    std::string cmd;
    for (const auto& a : args) cmd += " '" + a + "'";
    EXPECT_EQ(r.status, 2) << "hrt" << cmd << "\n" << r.err;
    EXPECT_EQ(std::count(r.err.begin(), r.err.end(), '\n'), 1) << "hrt" << cmd << "\n" << r.err;
    EXPECT_NE(r.err.find(fragment), std::string::npos) << "hrt" << cmd << "\n" << r.err;
    EXPECT_TRUE(r.out.empty()) << r.out;
  }
  std::vector<std::string> query(const std::vector<std::string>& pose_a, const std::vector<std::string>& extra = {}) {
    std::vector<std::string> a{"query", pebble_, pebble_, "--pose-a"};
    a.insert(a.end(), pose_a.begin(), pose_a.end());
    for (const char* x : {"--pose-b", "0.1", "0", "0", "0", "0", "0", "1"}) a.push_back(x);
    a.insert(a.end(), extra.begin(), extra.end());
    return a;
  }
  std::string pebble_;
};

TEST_F(HrtCli, QueryPoseRange) {
  // In range: runs (apart by 0.1 m, no contact).
  const HrtRun ok = run_hrt(query({"0", "0", "0", "0", "0", "0", "1"}, {"--json"}), true);
  ASSERT_EQ(ok.status, 0) << ok.err;
  EXPECT_TRUE(nlohmann::json::parse(ok.out).is_object());
  EXPECT_EQ(run_hrt(query({"1e4", "0", "0", "0", "0", "0", "1"}), true).status, 0);
  // 5e307 printed null for p_a, p_b, window origin and cell.
  expect_usage(query({"5e307", "0", "0", "0", "0", "0", "1"}, {"--json"}), "--pose-a: the position");
  expect_usage(query({"0", "0", "10000.5", "0", "0", "0", "1"}), "at most 10000 m");
  expect_usage(query({"nan", "0", "0", "0", "0", "0", "1"}), "--pose-a");
  expect_usage(query({"0", "0", "0", "0", "0", "0", "inf"}), "--pose-a");
  expect_usage(query({"0", "0", "0", "0", "0", "0", "2"}), "unit quaternion");
  expect_usage(query({"0", "0", "0", "0", "0", "0", "1e308"}), "unit quaternion");
}

TEST_F(HrtCli, QueryNumbersAreStrict) {
  // "" was read as 0; "1x" and "0x10" were refused on two lines or read as hex.
  for (const char* bad : {"", " ", "1x", "0.5.5", "--", "1e999", "0x10", "abc"})
    expect_usage(query({bad, "0", "0", "0", "0", "0", "1"}), "--pose-a");
  expect_usage(query({"0", "0", "0", "0", "0", "0", "1"}, {"--stiffness", ""}), "--stiffness");
  expect_usage(query({"0", "0", "0", "0", "0", "0", "1"}, {"--resolution", "32.5"}), "--resolution");
  expect_usage(query({"0", "0", "0", "0", "0", "0", "1"}, {"--repeat", ""}), "--repeat");
  expect_usage(query({"0", "0", "0", "0", "0", "0", "1"}, {"--max-patches", "7 "}), "--max-patches");
  // Wrong count of numbers: one line too.
  expect_usage({"query", pebble_, pebble_, "--pose-a", "0", "0", "0", "--pose-b", "0", "0", "0", "0", "0", "0", "1"},
               "--pose-a");
}

TEST_F(HrtCli, UnknownCommandIsNamed) {
  expect_usage({"bogus"}, "unknown command 'bogus' (commands: check, query, bench, run, gl-info)");
  expect_usage({"bogus", "--json"}, "unknown command 'bogus'");
  expect_usage({}, "a command is required (check, query, bench, run, gl-info)");
  expect_usage({"check"}, "check");
  expect_usage({"check", pebble_, "--bogus"}, "--bogus");
  EXPECT_EQ(run_hrt({"--help"}).status, 0);
  EXPECT_EQ(run_hrt({"query", "--help"}).status, 0);
}

TEST_F(HrtCli, BenchOptionsAreStrict) {
  const std::vector<std::string> base{"bench", "--a", pebble_, "--b", pebble_, "--pose-a", "0",
                                      "0",     "0",   "0",     "0",   "0",     "1"};
  auto with = [&](std::vector<std::string> extra) {
    std::vector<std::string> a = base;
    a.insert(a.end(), extra.begin(), extra.end());
    return a;
  };
  expect_usage(with({"--frames", ""}), "--frames");
  expect_usage(with({"--passes", "x"}), "--passes");
  expect_usage(with({"--resolutions", "32,,64"}), "--resolutions");
  expect_usage(with({"--copies", "1,2x"}), "--copies");
  expect_usage(with({"--settle-depth", ""}), "--settle-depth");
  expect_usage(with({"--settle-depth", "-1"}), "--settle-depth");
  expect_usage(with({"--path", "1e5", "0", "0"}), "--path");
  expect_usage(with({"--settle", "nan", "0", "1"}), "--settle");
  expect_usage(with({"--pose-b", "5e307", "0", "0", "0", "0", "0", "1"}), "--pose-b");
  expect_usage(with({"--frames", "0"}), "--frames");
}

TEST(FiniteJson, FindsTheFirstNonFiniteNumber) {
  using J = nlohmann::ordered_json;
  J ok = {{"a", 1.5}, {"b", {1, 2, {{"c", -0.0}}}}, {"n", nullptr}, {"s", "nan"}};
  EXPECT_EQ(hrt_cli::first_non_finite(ok), "");
  J bad = ok;
  bad["b"][2]["c"] = std::numeric_limits<double>::quiet_NaN();
  EXPECT_EQ(hrt_cli::first_non_finite(bad), "b/2/c");
  bad = ok;
  bad["z"] = {{"w", {0.0, HUGE_VAL}}};
  EXPECT_EQ(hrt_cli::first_non_finite(bad), "z/w/1");
  // Deep documents: no recursion.
  const J deep = J::parse(std::string(100000, '[') + "1" + std::string(100000, ']'));
  EXPECT_EQ(hrt_cli::first_non_finite(deep), "");
}

}  // namespace
