// The robot SDK's per-sample cost: Corrector::Apply / ApplyBatch on a realistic parameter set,
// against a hand-written loop doing the same arithmetic inline (the target: within 2x).
//
//   ninja -C build-perf corrector_bench && build-perf/bench/corrector_bench
//
// Parameter sets (magnitudes of core/simulator.h's RandomTruth):
//   linear     quadratic = 0: the Corrector folds misalignment * diag(scale) into one matrix
//   quadratic  quadratic != 0 (the solver's usual output): y = s .* (u - b); z = y + q .* y.^2
//   temp       quadratic plus four applied temperature effects (gyro x, y, z bias drift and an
//              accel z bias drift), samples with temp_c
// Each sample: accel 3x3 misalignment, gyro 3x3 matrix, gyro accel_coupling (a zero matrix in
// these sets, but Apply always multiplies it, so the hand loop does too).
// Counter "per_sample" is seconds per sample (shown as ns).
#include <cmath>
#include <cstdio>
#include <random>
#include <span>
#include <vector>

#include "Eigen/Core"
#include "Eigen/Geometry"
#include "benchmark/benchmark.h"
#include "client/sdk/corrector.h"
#include "core/params.h"

namespace {

using imucal::core::ParamSet;
using imucal::sdk::CalibratedSample;
using imucal::sdk::Corrector;
using imucal::sdk::RawSample;

constexpr int kSamples = 1024;  // 64 + 56 bytes per sample: ~120 KB in, out (L2-resident)

enum class Kind { kLinear, kQuadratic, kTemp };

ParamSet MakeParams(Kind kind) {
  ParamSet p;
  p.device = "robot-bench";
  p.accel.bias = Eigen::Vector3d(0.31, -0.52, 0.44);  // m/s^2
  p.accel.scale = Eigen::Vector3d(1.012, 0.991, 1.004);
  p.accel.tri_angles = Eigen::Vector3d(0.0021, -0.0034, 0.0017);
  p.accel.frame_angles = Eigen::Vector3d(0.008, -0.011, 0.004);
  if (kind != Kind::kLinear) p.accel.quadratic = Eigen::Vector3d(2.1e-5, -3.4e-5, 1.2e-5);
  p.gyro.matrix << 1.013, 0.0021, -0.0034,  //
      -0.0017, 0.986, 0.0029,               //
      0.0011, -0.0026, 1.019;
  p.gyro.bias = Eigen::Vector3d(0.0087, -0.0052, 0.0061);  // rad/s
  p.gyro_calibrated = true;
  if (kind == Kind::kTemp) {
    auto add = [&](imucal::core::Sensor sensor, int axis, double c) {
      imucal::core::Effect e;
      e.sensor = sensor;
      e.axis = axis;
      e.regressor = "temperature";
      e.coefficient = c;
      e.applied = true;
      p.effects.push_back(e);
    };
    add(imucal::core::Sensor::kGyro, 0, 1.2e-4);  // rad/s per degC
    add(imucal::core::Sensor::kGyro, 1, -0.8e-4);
    add(imucal::core::Sensor::kGyro, 2, 0.5e-4);
    add(imucal::core::Sensor::kAccel, 2, 2.0e-3);  // m/s^2 per degC
  }
  return p;
}

std::vector<RawSample> MakeSamples(bool with_temp) {
  std::mt19937_64 rng(7);
  std::normal_distribution<double> n(0.0, 1.0);
  std::vector<RawSample> v(kSamples);
  for (int i = 0; i < kSamples; ++i) {
    RawSample& s = v[static_cast<size_t>(i)];
    s.t_s = 0.005 * i;
    s.accel[0] = 0.3 + 0.05 * n(rng);
    s.accel[1] = -0.2 + 0.05 * n(rng);
    s.accel[2] = 9.81 + 0.05 * n(rng);
    for (double& g : s.gyro) g = 0.01 * n(rng);
    s.temp_c = with_temp ? 25.0 + 0.01 * i : std::nan("");
  }
  return v;
}

// The same arithmetic written out by hand: the reference the Corrector is judged against.
struct HandParams {
  double ab[3], as[3], aq[3], M[9], A[9];  // A = M * diag(scale) for the linear case
  double gb[3], G[9], C[9];
  double tc[6] = {};  // temperature coefficient per output (0 = none)
};

HandParams MakeHand(const ParamSet& p) {
  HandParams h{};
  const Eigen::Matrix3d M = p.accel.Misalignment();
  const Eigen::Matrix3d A = M * p.accel.scale.asDiagonal();
  for (int i = 0; i < 3; ++i) {
    h.ab[i] = p.accel.bias(i);
    h.as[i] = p.accel.scale(i);
    h.aq[i] = p.accel.quadratic(i);
    h.gb[i] = p.gyro.bias(i);
    for (int j = 0; j < 3; ++j) {
      h.M[3 * i + j] = M(i, j);
      h.A[3 * i + j] = A(i, j);
      h.G[3 * i + j] = p.gyro.matrix(i, j);
      h.C[3 * i + j] = p.gyro.accel_coupling(i, j);
    }
  }
  for (const imucal::core::Effect& e : p.effects) {
    h.tc[(e.sensor == imucal::core::Sensor::kAccel ? 0 : 3) + e.axis] += e.coefficient;
  }
  return h;
}

template <Kind kKind>
inline void HandApply(const HandParams& h, const RawSample& in, CalibratedSample* out) {
  double a[3];
  if constexpr (kKind == Kind::kLinear) {
    const double u0 = in.accel[0] - h.ab[0], u1 = in.accel[1] - h.ab[1], u2 = in.accel[2] - h.ab[2];
    for (int i = 0; i < 3; ++i) a[i] = h.A[3 * i] * u0 + h.A[3 * i + 1] * u1 + h.A[3 * i + 2] * u2;
  } else {
    double z[3];
    for (int i = 0; i < 3; ++i) {
      const double y = h.as[i] * (in.accel[i] - h.ab[i]);
      z[i] = y + h.aq[i] * y * y;
    }
    for (int i = 0; i < 3; ++i)
      a[i] = h.M[3 * i] * z[0] + h.M[3 * i + 1] * z[1] + h.M[3 * i + 2] * z[2];
  }
  const double g0 = in.gyro[0] - h.gb[0], g1 = in.gyro[1] - h.gb[1], g2 = in.gyro[2] - h.gb[2];
  double w[3];
  for (int i = 0; i < 3; ++i) {
    w[i] = h.G[3 * i] * g0 + h.G[3 * i + 1] * g1 + h.G[3 * i + 2] * g2 -
           (h.C[3 * i] * a[0] + h.C[3 * i + 1] * a[1] + h.C[3 * i + 2] * a[2]);
  }
  int skipped = 0;
  if constexpr (kKind == Kind::kTemp) {
    if (std::isnan(in.temp_c)) {
      skipped = 4;
    } else {
      for (int i = 0; i < 3; ++i) {
        a[i] -= h.tc[i] * in.temp_c;
        w[i] -= h.tc[3 + i] * in.temp_c;
      }
    }
  }
  for (int i = 0; i < 3; ++i) {
    out->accel_m_s2[i] = a[i];
    out->gyro_rad_s[i] = w[i];
  }
  out->effects_skipped = skipped;
}

void SetCounters(benchmark::State& state) {
  state.SetItemsProcessed(state.iterations() * kSamples);
  state.counters["per_sample"] = benchmark::Counter(
      kSamples, benchmark::Counter::kIsIterationInvariantRate | benchmark::Counter::kInvert);
}

template <Kind kKind>
void BM_CorrectorApply(benchmark::State& state) {
  const Corrector c = *Corrector::Create(MakeParams(kKind));
  const std::vector<RawSample> in = MakeSamples(kKind == Kind::kTemp);
  std::vector<CalibratedSample> out(in.size());
  for (auto _ : state) {
    for (size_t i = 0; i < in.size(); ++i) c.Apply(in[i], &out[i]);
    benchmark::DoNotOptimize(out.data());
    benchmark::ClobberMemory();
  }
  SetCounters(state);
}

template <Kind kKind>
void BM_CorrectorApplyBatch(benchmark::State& state) {
  const Corrector c = *Corrector::Create(MakeParams(kKind));
  const std::vector<RawSample> in = MakeSamples(kKind == Kind::kTemp);
  std::vector<CalibratedSample> out(in.size());
  for (auto _ : state) {
    absl::Status s = c.ApplyBatch(in, out);
    benchmark::DoNotOptimize(s);
    benchmark::DoNotOptimize(out.data());
    benchmark::ClobberMemory();
  }
  SetCounters(state);
}

template <Kind kKind>
void BM_HandLoop(benchmark::State& state) {
  const HandParams h = MakeHand(MakeParams(kKind));
  const std::vector<RawSample> in = MakeSamples(kKind == Kind::kTemp);
  std::vector<CalibratedSample> out(in.size());
  // Check the reference against the Corrector once, so both compute the same thing.
  {
    const Corrector c = *Corrector::Create(MakeParams(kKind));
    double worst = 0;
    for (size_t i = 0; i < in.size(); ++i) {
      CalibratedSample x, y;
      c.Apply(in[i], &x);
      HandApply<kKind>(h, in[i], &y);
      for (int k = 0; k < 3; ++k) {
        worst = std::max(worst, std::abs(x.accel_m_s2[k] - y.accel_m_s2[k]));
        worst = std::max(worst, std::abs(x.gyro_rad_s[k] - y.gyro_rad_s[k]));
      }
    }
    if (worst > 1e-9) {
      state.SkipWithError("hand loop disagrees with Corrector::Apply");
      return;
    }
  }
  for (auto _ : state) {
    for (size_t i = 0; i < in.size(); ++i) HandApply<kKind>(h, in[i], &out[i]);
    benchmark::DoNotOptimize(out.data());
    benchmark::ClobberMemory();
  }
  SetCounters(state);
}

// sdk::Stream (issue 27): the static model then a learnt dynamic gyro block of `taps` taps
// (range(0); -1: no block, the Stream alone) at `dilation` (range(1)), per sample.
imucal::core::ParamSet WithBlock(imucal::core::ParamSet p, int taps, int dilation) {
  if (taps < 0) return p;
  imucal::core::DynamicGyro b;
  b.rate_hz = 200.0;
  b.delay_s = 0.0026;
  b.odd_rate = Eigen::Vector3d(1e-3, -1e-3, 5e-4);
  b.taps = taps;
  b.dilation = dilation;
  for (int i = 0; i < 18 * taps; ++i) b.weights.push_back(1e-3 * ((i % 7) - 3));
  b.envelope.max_abs_rate_rad_s = Eigen::Vector3d::Constant(1e9);
  b.envelope.max_abs_accel_m_s2 = Eigen::Vector3d::Constant(1e9);
  p.dynamic_gyro = b;
  return p;
}

void BM_StreamApply(benchmark::State& state) {
  const int taps = static_cast<int>(state.range(0));
  const Corrector c = *Corrector::Create(
      WithBlock(MakeParams(Kind::kLinear), taps, static_cast<int>(state.range(1))));
  imucal::sdk::Stream stream = *c.NewStream(200.0);
  std::vector<RawSample> in = MakeSamples(false);
  std::vector<CalibratedSample> out(in.size());
  for (auto _ : state) {
    stream.Reset();  // each pass a fresh stream: its times start again
    for (size_t i = 0; i < in.size(); ++i) stream.Apply(in[i], &out[i]);
    benchmark::DoNotOptimize(out.data());
    benchmark::ClobberMemory();
  }
  SetCounters(state);
}

BENCHMARK(BM_StreamApply)->Args({-1, 1})->Args({0, 1})->Args({8, 3})->Args({29, 16});

BENCHMARK(BM_CorrectorApply<Kind::kLinear>);
BENCHMARK(BM_CorrectorApplyBatch<Kind::kLinear>);
BENCHMARK(BM_HandLoop<Kind::kLinear>);
BENCHMARK(BM_CorrectorApply<Kind::kQuadratic>);
BENCHMARK(BM_CorrectorApplyBatch<Kind::kQuadratic>);
BENCHMARK(BM_HandLoop<Kind::kQuadratic>);
BENCHMARK(BM_CorrectorApply<Kind::kTemp>);
BENCHMARK(BM_CorrectorApplyBatch<Kind::kTemp>);
BENCHMARK(BM_HandLoop<Kind::kTemp>);

}  // namespace

BENCHMARK_MAIN();
