// `imucal noise --session S`: a robot's stored session read from the server (GetSession for its
// device, GetDevice for the units, ReadSamples for the samples) into the capture that
// noise_command.cc analyses as it analyses files. Here, not in noise_command.cc, because
// imucal_cli has no gRPC (client/CMakeLists.txt): RunNoise, which main.cc calls, is this
// library's `RunNoiseWith` with the session reader.
#include <chrono>
#include <cmath>
#include <memory>
#include <optional>
#include <string>
#include <utility>
#include <vector>

#include "absl/strings/str_cat.h"
#include "client/cli/commands.h"
#include "client/cli/noise_source.h"
#include "client/cli/server_common.h"

namespace imucal::cli {
namespace {

namespace pb = imucal::v1;

// An hour at 200 Hz is 720,000 samples (46 MB on the wire): seconds on a LAN. The most a
// session may hold (10 M samples) is 640 MB.
constexpr auto kReadDeadline = std::chrono::minutes(10);

// Appends one ReadSamples message to the capture (a sample without temperature gets NaN there);
// `with_temp` counts the samples that came with one.
absl::Status Append(const pb::SampleBatch& b, core::Capture* cap, size_t* with_temp) {
  const int n = b.t_s_size();
  if (b.accel_size() != 3 * n || b.gyro_size() != 3 * n ||
      (b.temp_c_size() != 0 && b.temp_c_size() != n)) {
    return absl::DataLossError(
        absl::StrCat("ReadSamples: batch ", b.seq(), " has columns of different lengths"));
  }
  for (int i = 0; i < n; ++i) {
    cap->t_s.push_back(b.t_s(i));
    cap->accel.emplace_back(b.accel(3 * i), b.accel(3 * i + 1), b.accel(3 * i + 2));
    cap->gyro.emplace_back(b.gyro(3 * i), b.gyro(3 * i + 1), b.gyro(3 * i + 2));
    cap->temp.push_back(b.temp_c_size() == n ? b.temp_c(i) : NAN);
  }
  if (b.temp_c_size() == n) *with_temp += static_cast<size_t>(n);
  return absl::OkStatus();
}

int ReadSession(const std::string& session_id, const std::optional<std::string>& server_flag,
                NoiseInput* in) {
  Server server = ConnectWith(ServerAddress(server_flag), ConnectionOptions());
  pb::Session session;
  if (grpc::Status s = GetSession(server, session_id, &session); !s.ok())
    return RpcError(server, s);
  pb::GetDeviceRequest device_request;
  device_request.set_device_id(session.device_id());
  pb::Device device;
  if (grpc::Status s = server.devices->GetDevice(CallContext().get(), device_request, &device);
      !s.ok())
    return RpcError(server, s);
  absl::StatusOr<core::AccelUnit> accel_unit = core::ParseAccelUnit(device.accel_unit());
  absl::StatusOr<core::GyroUnit> gyro_unit = core::ParseGyroUnit(device.gyro_unit());
  if (!accel_unit.ok()) return ReportError(accel_unit.status());
  if (!gyro_unit.ok()) return ReportError(gyro_unit.status());

  core::Capture& cap = in->capture;
  cap = core::Capture();
  cap.device = device.id();
  cap.accel_unit = *accel_unit;
  cap.gyro_unit = *gyro_unit;
  cap.rate_hz = device.nominal_rate_hz();
  cap.t_s.reserve(static_cast<size_t>(session.samples()));
  cap.accel.reserve(static_cast<size_t>(session.samples()));
  cap.gyro.reserve(static_cast<size_t>(session.samples()));
  cap.temp.reserve(static_cast<size_t>(session.samples()));
  size_t with_temp = 0;
  {
    grpc::ClientContext context;
    context.set_deadline(std::chrono::system_clock::now() + kReadDeadline);
    pb::ReadSamplesRequest request;
    request.set_session_id(session_id);
    std::unique_ptr<grpc::ClientReader<pb::SampleBatch>> reader =
        server.sessions->ReadSamples(&context, request);
    pb::SampleBatch batch;
    absl::Status appended;
    while (appended.ok() && reader->Read(&batch)) appended = Append(batch, &cap, &with_temp);
    if (!appended.ok()) {
      context.TryCancel();
      reader->Finish().ok();
      return ReportError(appended);
    }
    if (grpc::Status s = reader->Finish(); !s.ok()) return RpcError(server, s);
  }
  // Temperature for every sample or none, as the server's solve takes it.
  if (with_temp < cap.size()) {
    if (with_temp > 0) {
      in->report.notes.push_back(absl::StrCat("temperature left out: ", cap.size() - with_temp,
                                              " of the session's ", cap.size(),
                                              " samples came without it"));
    }
    cap.temp.clear();
    cap.temp.shrink_to_fit();
  }
  if (cap.size() == 0) {
    return ReportError(absl::FailedPreconditionError(
        absl::StrCat("session ", session_id, " holds no samples yet")));
  }
  if (absl::Status s = core::ValidateCapture(cap); !s.ok()) {
    return ReportError(absl::DataLossError(
        absl::StrCat("session ", session_id, "'s samples as served: ", s.message())));
  }
  in->report.format = absl::StrCat("stored session of ", device.id(), " at ", server.address,
                                   ", accel ", device.accel_unit(), ", gyro ", device.gyro_unit());
  in->report.paths = {session_id};
  in->session = NoiseSession{session_id, device.id(), server.address};
  return kExitOk;
}

}  // namespace

int RunNoise(const std::vector<std::string>& args) { return RunNoiseWith(args, ReadSession); }

}  // namespace imucal::cli
