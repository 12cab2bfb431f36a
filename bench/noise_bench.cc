// `imucal noise` on a 6-hour rest at 200 Hz (4.32 M samples x 6 axes), parsing included: the
// capture file (imucal CSV, written once into the temp directory with white noise and a rate
// random walk of known N and K) read by the importer registry, then the overlapping Allan
// deviation of every axis and the figures (core/allan.h ComputeNoise), as the CLI runs them.
// Counters: peak_rss_mb, the process's peak resident memory after the run (the generator
// streams the file and holds no samples, so the peak is the import's and the analysis'), and
// N, K of gyro x against the truth.
//
// BM_AllanClusterTimes/P: the Allan deviation of one 4.32 M series at P cluster times per
// decade (10 is what ComputeNoise uses); rss_growth_mb is the peak resident memory the call
// added. Run each P in its own process for a clean peak:
//   build/bench/noise_bench --benchmark_filter='BM_AllanClusterTimes/10$'
#include <sys/resource.h>

#include <array>
#include <charconv>
#include <cmath>
#include <cstdio>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "benchmark/benchmark.h"
#include "core/allan.h"
#include "core/capture.h"
#include "importers/registry.h"

namespace imucal::core {
namespace {

constexpr double kRateHz = 200.0;
constexpr size_t kSamples = static_cast<size_t>(6 * 3600 * kRateHz);  // 4.32 M
constexpr double kGyroN = 1.4e-4;                                     // rad/s/sqrt(Hz)
constexpr double kGyroK = 2e-6;                                       // rad/s^2/sqrt(Hz)
constexpr double kAccelN = 1.4e-3;                                    // m/s^2/sqrt(Hz)
constexpr double kAccelK = 2e-5;                                      // m/s^3/sqrt(Hz)

double PeakRssMb() {
  rusage usage{};
  getrusage(RUSAGE_SELF, &usage);
  return static_cast<double>(usage.ru_maxrss) / 1024.0;  // ru_maxrss is in KiB on Linux
}

void Append(double value, std::string* out) {
  std::array<char, 32> buffer;
  const auto r = std::to_chars(buffer.data(), buffer.data() + buffer.size(), value,
                               std::chars_format::general, 9);
  out->append(buffer.data(), r.ptr);
}

// The 6-hour rest, written once (about 450 MB) and streamed: never held in memory.
const std::string& RestFile() {
  static const std::string* const kPath = [] {
    auto* path = new std::string(
        (std::filesystem::temp_directory_path() / "imucal_noise_bench_6h.csv").string());
    std::FILE* f = std::fopen(path->c_str(), "w");
    std::fputs(
        "# imucal-capture v1\n# device=bench\n# accel_unit=m/s^2\n# gyro_unit=rad/s\n"
        "# gravity=9.80665\n# rate_hz=200\nt,ax,ay,az,gx,gy,gz\n",
        f);
    std::mt19937_64 rng(6);
    std::normal_distribution<double> normal;
    std::array<double, 6> walk{};
    std::string line;
    for (size_t i = 0; i < kSamples; ++i) {
      line.clear();
      Append(static_cast<double>(i) / kRateHz, &line);
      for (int k = 0; k < 6; ++k) {
        const double n = k < 3 ? kAccelN : kGyroN, rw = k < 3 ? kAccelK : kGyroK;
        walk[k] += rw / std::sqrt(kRateHz) * normal(rng);
        line.push_back(',');
        Append((k == 2 ? kStandardGravity : 0.0) + walk[k] + n * std::sqrt(kRateHz) * normal(rng),
               &line);
      }
      line.push_back('\n');
      std::fwrite(line.data(), 1, line.size(), f);
    }
    std::fclose(f);
    return path;
  }();
  return *kPath;
}

void BM_RestNoise6h(benchmark::State& state) {
  const std::string& path = RestFile();
  double n = 0, k = 0;
  for (auto _ : state) {
    absl::StatusOr<Capture> capture = importers::ImportCapture({path}, importers::ImportOptions{});
    if (!capture.ok()) {
      state.SkipWithError(std::string(capture.status().message()).c_str());
      return;
    }
    absl::StatusOr<NoiseAnalysis> na =
        ComputeNoise(*capture, 0, capture->size(), AccelParams(), GyroParams());
    if (!na.ok()) {
      state.SkipWithError(std::string(na.status().message()).c_str());
      return;
    }
    n = na->readings[3].noise_density.value;
    k = na->readings[3].random_walk.value;
  }
  state.counters["samples"] = static_cast<double>(kSamples);
  state.counters["peak_rss_mb"] = PeakRssMb();
  state.counters["gyro_x_N_ratio"] = n / kGyroN;
  state.counters["gyro_x_K_ratio"] = k / kGyroK;
}
BENCHMARK(BM_RestNoise6h)->Unit(benchmark::kSecond)->Iterations(1);

void BM_AllanClusterTimes(benchmark::State& state) {
  std::mt19937_64 rng(7);
  std::normal_distribution<double> normal;
  std::vector<double> series(kSamples);
  for (double& v : series) v = normal(rng);
  const std::vector<size_t> m = LogSpacedClusterSizes(kSamples, static_cast<int>(state.range(0)));
  const double before = PeakRssMb();
  for (auto _ : state) {
    const std::vector<double> adev = OverlappingAllanDeviation(series, kRateHz, m);
    benchmark::DoNotOptimize(adev.data());
  }
  state.counters["cluster_times"] = static_cast<double>(m.size());
  state.counters["rss_growth_mb"] = PeakRssMb() - before;
}
BENCHMARK(BM_AllanClusterTimes)->Arg(10)->Arg(100)->Unit(benchmark::kSecond)->Iterations(1);

}  // namespace
}  // namespace imucal::core

BENCHMARK_MAIN();
