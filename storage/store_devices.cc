// Store: devices (store.h "Devices"). A device's active_version is derived, from the
// param_versions table.
#include <cmath>
#include <optional>
#include <utility>

#include "storage/status_macros.h"
#include "storage/store.h"
#include "storage/store_internal.h"
#include "util/db.h"
#include "util/str_util.h"

namespace imucal::storage {
namespace {

// active_version: a lookup in the partial index param_versions_active.
constexpr char kSelectDevice[] =
    "SELECT d.id, d.sensor_model, d.nominal_rate_hz, d.accel_unit, d.gyro_unit, "
    "d.created_at_us, COALESCE((SELECT v.version FROM param_versions v "
    "WHERE v.device_id = d.id AND v.state = 'active'), 0) "
    "FROM devices d WHERE d.id = ?1";
constexpr char kSelectDevices[] =
    "SELECT d.id, d.sensor_model, d.nominal_rate_hz, d.accel_unit, d.gyro_unit, "
    "d.created_at_us, COALESCE((SELECT v.version FROM param_versions v "
    "WHERE v.device_id = d.id AND v.state = 'active'), 0) "
    "FROM devices d WHERE d.id > ?1 ORDER BY d.id LIMIT ?2";
constexpr char kInsertDevice[] =
    "INSERT INTO devices (id, sensor_model, nominal_rate_hz, accel_unit, gyro_unit, "
    "created_at_us) VALUES (?1, ?2, ?3, ?4, ?5, ?6)";

// Columns as in kSelectDevice.
Device ReadDevice(const sql::Statement& st) {
  Device d;
  d.id = st.ColumnText(0);
  d.sensor_model = st.ColumnText(1);
  d.nominal_rate_hz = st.ColumnDouble(2);
  d.accel_unit = st.ColumnText(3);
  d.gyro_unit = st.ColumnText(4);
  d.created_at = FromMicros(st.ColumnInt64(5));
  d.active_version = static_cast<int>(st.ColumnInt64(6));
  return d;
}

absl::StatusOr<std::optional<Device>> FindDevice(sql::Connection& conn, std::string_view id) {
  return sql::ReadRow(conn, kSelectDevice, ReadDevice, id);
}

// A device registering again (robots do at every boot) must say the same thing.
absl::Status SameRegistration(const Device& stored, const Device& again) {
  auto differs = [&](std::string_view field, const auto& was, const auto& now) {
    return absl::AlreadyExistsError(Cat("device '", stored.id, "' is already registered with ",
                                        field, " ", was, ", not ", now));
  };
  if (stored.sensor_model != again.sensor_model) {
    return differs("sensor_model", stored.sensor_model, again.sensor_model);
  }
  if (stored.nominal_rate_hz != again.nominal_rate_hz) {
    return differs("nominal_rate_hz", stored.nominal_rate_hz, again.nominal_rate_hz);
  }
  if (stored.accel_unit != again.accel_unit) {
    return differs("accel_unit", stored.accel_unit, again.accel_unit);
  }
  if (stored.gyro_unit != again.gyro_unit) {
    return differs("gyro_unit", stored.gyro_unit, again.gyro_unit);
  }
  return absl::OkStatus();
}

}  // namespace

absl::StatusOr<Device> LoadDevice(sql::Connection& conn, std::string_view id) {
  IMUCAL_ASSIGN_OR_RETURN(std::optional<Device> d, FindDevice(conn, id));
  if (!d) return absl::NotFoundError(Cat("no device '", id, "'"));
  return *std::move(d);
}

absl::StatusOr<Device> Store::CreateDevice(const Device& device, std::string_view actor) {
  constexpr std::string_view kOp = "CreateDevice";
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(device.id, "device id")));
  IMUCAL_RETURN_IF_ERROR(Annotate(kOp, NonEmpty(actor, "actor")));
  if (!std::isfinite(device.nominal_rate_hz) || device.nominal_rate_hz < 0) {
    return WithContext(
        kOp, absl::InvalidArgumentError(
                 Cat("nominal_rate_hz ", device.nominal_rate_hz, " is not a non-negative number")));
  }
  std::lock_guard lock(write_mu_);
  return InTransaction(kOp, *writer_, [&](sql::Connection& conn) -> absl::StatusOr<Device> {
    IMUCAL_ASSIGN_OR_RETURN(std::optional<Device> existing, FindDevice(conn, device.id));
    if (existing) {
      IMUCAL_RETURN_IF_ERROR(SameRegistration(*existing, device));
      return *std::move(existing);
    }
    Device d = device;
    d.created_at = Now();
    IMUCAL_RETURN_IF_ERROR(sql::RunStatement(conn, kInsertDevice, d.id, d.sensor_model,
                                             d.nominal_rate_hz, d.accel_unit, d.gyro_unit,
                                             Micros(d.created_at)));
    IMUCAL_RETURN_IF_ERROR(InsertAudit(conn, d.created_at, actor, "device.create",
                                       DeviceTarget(d.id),
                                       Cat("sensor ", d.sensor_model, ", ", d.nominal_rate_hz,
                                           " Hz, accel ", d.accel_unit, ", gyro ", d.gyro_unit)));
    return d;
  });
}

absl::StatusOr<Device> Store::GetDevice(std::string_view id) {
  ReadLease lease = AcquireReader();
  return Annotate("GetDevice", LoadDevice(lease.conn(), id));
}

absl::StatusOr<std::vector<Device>> Store::ListDevices(std::string_view after_id, int limit) {
  ReadLease lease = AcquireReader();
  return Annotate("ListDevices", sql::ReadRows(lease.conn(), kSelectDevices, ReadDevice, after_id,
                                               SqlLimit(limit)));
}

}  // namespace imucal::storage
