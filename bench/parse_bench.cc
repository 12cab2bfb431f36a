// Capture parsing speed: the CLI and the server read every upload through these parsers, so a
// 50,000-line capture should cost a few milliseconds, not a noticeable pause.
#include <array>
#include <charconv>
#include <cmath>
#include <filesystem>
#include <random>
#include <string>
#include <vector>

#include "benchmark/benchmark.h"
#include "core/capture.h"
#include "importers/imucal_csv.h"
#include "importers/imutk.h"
#include "importers/registry.h"

namespace imucal::core {
namespace {

constexpr int kRows = 50000;

void AppendFixed(double value, int decimals, std::string* out) {
  std::array<char, 32> buffer;
  const auto result = std::to_chars(buffer.data(), buffer.data() + buffer.size(), value,
                                    std::chars_format::fixed, decimals);
  out->append(buffer.data(), result.ptr);
}

// A 200 Hz capture with 8 columns in the precision a logger writes (as in capture-format.md):
// mostly static with noise, the sensor slowly turning so that values vary in sign and size.
std::string GeneratedCaptureText() {
  std::mt19937 rng(42);
  std::normal_distribution<double> noise(0.0, 1.0);
  std::string text =
      "# imucal-capture v1\n# device=bench\n# accel_unit=m/s^2\n# gyro_unit=rad/s\n"
      "# gravity=9.80665\n# rate_hz=200\nt,ax,ay,az,gx,gy,gz,temp\n";
  text.reserve(static_cast<size_t>(kRows) * 72);
  for (int i = 0; i < kRows; ++i) {
    const double t_s = 0.005 * i;
    const double angle = 0.05 * t_s;
    AppendFixed(t_s, 6, &text);
    for (const double a : {9.80665 * std::sin(angle), -0.02, 9.80665 * std::cos(angle)}) {
      text.push_back(',');
      AppendFixed(a + 0.01 * noise(rng), 4, &text);
    }
    for (const double w : {0.001, -0.0003, 0.05}) {
      text.push_back(',');
      AppendFixed(w + 0.001 * noise(rng), 5, &text);
    }
    text.push_back(',');
    AppendFixed(24.8 + 0.001 * t_s, 2, &text);
    text.push_back('\n');
  }
  return text;
}

const std::string& CaptureText() {
  static const std::string* const kText = new std::string(GeneratedCaptureText());
  return *kText;
}

void BM_ParseImucalCsv(benchmark::State& state) {
  const std::string& text = CaptureText();
  for (auto _ : state) {
    absl::StatusOr<Capture> capture = importers::ParseImucalCsv(text, "bench.csv");
    if (!capture.ok()) {
      state.SkipWithError(std::string(capture.status().message()).c_str());
      return;
    }
    benchmark::DoNotOptimize(capture->t_s.data());
  }
  state.SetBytesProcessed(state.iterations() * static_cast<int64_t>(text.size()));
  state.SetItemsProcessed(state.iterations() * kRows);
  state.counters["rows"] = kRows;
}
BENCHMARK(BM_ParseImucalCsv)->Unit(benchmark::kMillisecond);

void BM_FormatImucalCsv(benchmark::State& state) {
  absl::StatusOr<Capture> capture = importers::ParseImucalCsv(CaptureText(), "bench.csv");
  if (!capture.ok()) {
    state.SkipWithError(std::string(capture.status().message()).c_str());
    return;
  }
  size_t bytes = 0;
  for (auto _ : state) {
    const std::string text = importers::FormatImucalCsv(*capture);
    bytes = text.size();
    benchmark::DoNotOptimize(text.data());
  }
  state.SetBytesProcessed(state.iterations() * static_cast<int64_t>(bytes));
  state.SetItemsProcessed(state.iterations() * kRows);
}
BENCHMARK(BM_FormatImucalCsv)->Unit(benchmark::kMillisecond);

// The real Xsens pair from imu_tk (2 x 51,175 rows, 3.3 MB each), read from disk.
void BM_ReadXsensImuTkPair(benchmark::State& state) {
  const std::string dir = IMUCAL_SHARED_DIR "/data/real/xsens-imutk/";
  const std::string accel_path = dir + "xsens_acc.mat";
  const std::string gyro_path = dir + "xsens_gyro.mat";
  std::error_code error;
  if (!std::filesystem::exists(accel_path, error) || !std::filesystem::exists(gyro_path, error)) {
    state.SkipWithError("the Xsens pair is not in IMUCAL_SHARED_DIR");
    return;
  }
  const auto bytes = static_cast<int64_t>(std::filesystem::file_size(accel_path) +
                                          std::filesystem::file_size(gyro_path));
  size_t rows = 0;
  for (auto _ : state) {
    absl::StatusOr<Capture> capture =
        importers::ReadImuTkPair(accel_path, gyro_path, importers::ImportOptions{});
    if (!capture.ok()) {
      state.SkipWithError(std::string(capture.status().message()).c_str());
      return;
    }
    rows = capture->size();
    benchmark::DoNotOptimize(capture->t_s.data());
  }
  state.SetBytesProcessed(state.iterations() * bytes);
  state.SetItemsProcessed(state.iterations() * static_cast<int64_t>(rows));
  state.counters["rows"] = static_cast<double>(rows);
}
BENCHMARK(BM_ReadXsensImuTkPair)->Unit(benchmark::kMillisecond);

}  // namespace
}  // namespace imucal::core

BENCHMARK_MAIN();
