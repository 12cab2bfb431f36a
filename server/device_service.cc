#include "server/device_service.h"

#include <optional>
#include <regex>
#include <string>

#include "absl/strings/numbers.h"
#include "absl/strings/str_cat.h"
#include "core/capture.h"
#include "server/convert.h"
#include "server/unary.h"
#include "util/text_check.h"

namespace imucal::server {
namespace {

absl::Status ValidateDevice(const v1::Device& device) {
  static const std::regex kId("[A-Za-z0-9._-]{1,64}");
  if (!std::regex_match(device.id(), kId))
    return absl::InvalidArgumentError("device.id: must match [A-Za-z0-9._-]{1,64}");
  if (device.sensor_model().size() > 256)
    return absl::InvalidArgumentError("device.sensor_model: at most 256 characters");
  // Shown in `imucal devices` and reports: no control character, C0 or C1.
  if (std::optional<UnreadableChar> bad = FindUnreadableChar(device.sensor_model()))
    return absl::InvalidArgumentError(bad->Message("device.sensor_model"));
  if (!(device.nominal_rate_hz() > 0 && device.nominal_rate_hz() <= 100000))
    return absl::InvalidArgumentError("device.nominal_rate_hz: must be in (0, 100000] Hz");
  if (!core::ParseAccelUnit(device.accel_unit()).ok())
    return absl::InvalidArgumentError("device.accel_unit: must be \"m/s^2\", \"g\" or \"counts\"");
  if (!core::ParseGyroUnit(device.gyro_unit()).ok())
    return absl::InvalidArgumentError(
        "device.gyro_unit: must be \"rad/s\", \"deg/s\" or \"counts\"");
  return absl::OkStatus();
}

}  // namespace

absl::Status DeviceServiceImpl::DoRegister(const grpc::CallbackServerContext& context,
                                           const v1::RegisterDeviceRequest& request,
                                           v1::Device* response) {
  // A robot registers only itself.
  absl::StatusOr<PrincipalRef> who =
      auth_->AuthorizeForDevice(context, Rpc::kRegisterDevice, request.device().id());
  if (!who.ok()) return who.status();
  if (absl::Status s = ValidateDevice(request.device()); !s.ok()) return s;
  // Robots register at every boot: the store returns the existing device for the same
  // metadata and AlreadyExists (naming the field) for different metadata.
  absl::StatusOr<storage::Device> stored =
      store_->CreateDevice(FromProto(request.device()), (*who)->actor);
  if (!stored.ok()) return stored.status();
  *response = ToProto(*stored);
  return absl::OkStatus();
}

grpc::ServerUnaryReactor* DeviceServiceImpl::RegisterDevice(
    grpc::CallbackServerContext* context, const v1::RegisterDeviceRequest* request,
    v1::Device* response) {
  return FinishUnary(context, DoRegister(*context, *request, response));
}

grpc::ServerUnaryReactor* DeviceServiceImpl::GetDevice(grpc::CallbackServerContext* context,
                                                       const v1::GetDeviceRequest* request,
                                                       v1::Device* response) {
  absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kGetDevice);
  if (!who.ok()) return FinishUnary(context, who.status());
  if (request->device_id().empty())
    return FinishUnary(context, absl::InvalidArgumentError("device_id: required"));
  // A robot reads only its own device; checked before the lookup, so whether another device
  // exists is not told either.
  if (absl::Status s =
          auth_->AuthorizeDevice(*context, **who, Rpc::kGetDevice, request->device_id());
      !s.ok())
    return FinishUnary(context, s);
  absl::StatusOr<storage::Device> device = store_->GetDevice(request->device_id());
  if (!device.ok()) return FinishUnary(context, device.status());
  *response = ToProto(*device);
  return FinishUnary(context, absl::OkStatus());
}

grpc::ServerUnaryReactor* DeviceServiceImpl::ListDevices(grpc::CallbackServerContext* context,
                                                         const v1::ListDevicesRequest* request,
                                                         v1::ListDevicesResponse* response) {
  if (absl::StatusOr<PrincipalRef> who = auth_->Authorize(*context, Rpc::kListDevices); !who.ok())
    return FinishUnary(context, who.status());
  absl::StatusOr<int> size = PageSize(request->page_size(), 1000);
  if (!size.ok()) return FinishUnary(context, size.status());
  // One more than the page: whether there is a next page.
  absl::StatusOr<std::vector<storage::Device>> devices =
      store_->ListDevices(request->page_token(), *size + 1);
  if (!devices.ok()) return FinishUnary(context, devices.status());
  const bool more = devices->size() > static_cast<size_t>(*size);
  if (more) devices->pop_back();
  for (const storage::Device& d : *devices) *response->add_devices() = ToProto(d);
  if (more) response->set_next_page_token(devices->back().id);
  return FinishUnary(context, absl::OkStatus());
}

}  // namespace imucal::server
