// Robustness: random byte flips and truncations of every file of a bundle,
// loaded with hash verification off (so the parsers see the damage), must end
// in a BundleError or a successful load -- never a crash, another exception
// type, or a hang. A flip may leave a valid file (a low mantissa bit of a
// position), so success is allowed for flips; a truncation must be rejected.
// Fixed seed: the same mutations every run.
#include <chrono>
#include <cstdlib>
#include <cstdio>
#include <filesystem>
#include <random>

#include <gtest/gtest.h>

#include "hrt/model.h"
#include "test_io_writer.h"

using namespace hrt_test;
namespace fs = std::filesystem;

namespace {

// A generous per-load bound (a clean load of the cube takes ~1 ms, of a golden
// bundle some tens of ms): a parser that loops on corrupt counts would blow it.
constexpr double kMaxSecondsPerLoad = 5.0;

struct Stats {
  int rejected = 0, loaded = 0;
};

// Mutates `file` of the bundle in `work` (a copy of `base`) `iterations` times.
void fuzz_file(const std::string& base, const std::string& work, const std::string& file, int iterations,
               std::mt19937& rng, Stats& stats) {
  const std::string original = read_bytes(base + "/" + file);
  ASSERT_FALSE(original.empty());
  hrt::LoadOptions opts;
  opts.verify_hashes = false;
  for (int it = 0; it < iterations; ++it) {
    std::string bytes = original;
    const int mode = static_cast<int>(rng() % 4);  // 0, 1: flips; 2: truncation; 3: both
    bool truncated = false;
    if (mode != 2) {
      const int flips = 1 + static_cast<int>(rng() % 8);
      for (int k = 0; k < flips; ++k) {
        // Half of the flips hit the first 512 bytes, where the headers are.
        const size_t span = (rng() % 2) ? std::min<size_t>(512, bytes.size()) : bytes.size();
        const size_t at = rng() % span;
        bytes[at] = static_cast<char>(bytes[at] ^ static_cast<char>(1 + rng() % 255));
      }
    }
    if (mode >= 2) {
      bytes.resize(rng() % bytes.size());
      truncated = true;
    }
    write_bytes(work + "/" + file, bytes);
    const auto t0 = std::chrono::steady_clock::now();
    bool loaded = false;
    try {
      hrt::load_bundle(work, opts);
      loaded = true;
    } catch (const hrt::BundleError& e) {
      // One line naming a file of the bundle (not always the damaged one: a
      // flipped UV in coarse.ply is caught by the atlas coverage check).
      const std::string what = e.what();
      EXPECT_EQ(what.rfind(work, 0), 0u) << what;
      EXPECT_EQ(what.find('\n'), std::string::npos) << what;
    } catch (const std::exception& e) {
      ADD_FAILURE() << file << " iteration " << it << ": " << typeid(e).name()
                    << " instead of BundleError: " << e.what();
    }
    const double dt = std::chrono::duration<double>(std::chrono::steady_clock::now() - t0).count();
    EXPECT_LT(dt, kMaxSecondsPerLoad) << file << " iteration " << it;
    if (truncated && file != "manifest.json") {
      // A truncated binary file is always rejected (its length no longer matches).
      EXPECT_FALSE(loaded) << file << " truncated to " << bytes.size() << " bytes loaded";
    }
    (loaded ? stats.loaded : stats.rejected)++;
  }
  write_bytes(work + "/" + file, original);
}

// HRT_IO_FUZZ_SCALE=k multiplies the iteration counts (deeper runs by hand).
int scaled(int n) {
  const char* s = std::getenv("HRT_IO_FUZZ_SCALE");
  return s ? n * std::max(1, std::atoi(s)) : n;
}

void fuzz_bundle(const std::string& base, const std::string& tag, int per_file) {
  per_file = scaled(per_file);
  const std::string work = fresh_dir("fuzz_" + tag);
  copy_dir(base, work);
  ASSERT_NO_THROW(hrt::load_bundle(work)) << "the unmutated bundle must load";
  std::mt19937 rng(20240611);
  for (const char* file : {"manifest.json", "coarse.ply", "atlas.exr", "pieces.ply"}) {
    Stats stats;
    fuzz_file(base, work, file, per_file, rng, stats);
    std::printf("fuzz %s %-14s %3d mutations: %3d rejected, %3d still valid\n", tag.c_str(), file, per_file,
                stats.rejected, stats.loaded);
    EXPECT_GT(stats.rejected, per_file / 4) << "most mutations of " << file << " should be caught";
  }
  remove_tree(work);
}

TEST(IoFuzz, CubeBundleSurvivesByteFlipsAndTruncations) {
  const std::string base = fresh_dir("fuzz_base");
  write_bundle(base, make_cube());
  fuzz_bundle(base, "cube", 100);
  remove_tree(base);
}

TEST(IoFuzz, GoldenBundleSurvivesByteFlipsAndTruncations) {
  // The smallest golden bundle (by total size), so the loop stays fast.
  std::string best;
  uintmax_t best_size = UINTMAX_MAX;
  if (fs::is_directory(golden_dir())) {
    for (const auto& e : fs::directory_iterator(golden_dir())) {
      if (!e.is_directory() || e.path().extension() != ".hbundle") continue;
      uintmax_t size = 0;
      for (const auto& f : fs::directory_iterator(e.path()))
        if (f.is_regular_file()) size += f.file_size();
      if (size < best_size) best_size = size, best = e.path().string();
    }
  }
  if (best.empty())
    GTEST_FAIL() << "no golden bundle in " << golden_dir() << " (tests/golden/make_golden.py writes them)";
  fuzz_bundle(best, "golden", 40);
}

}  // namespace
