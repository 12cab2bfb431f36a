// Store: devices (storage/store_devices.cc).
#include <string>
#include <vector>

#include "gmock/gmock.h"
#include "gtest/gtest.h"
#include "storage/store.h"
#include "tests/storage/store_test_util.h"

namespace imucal::storage {
namespace {

using ::testing::HasSubstr;

TEST_P(StoreTest, DevicesAreCreatedReadAndListed) {
  ASSERT_OK_AND_ASSIGN(Device b, store_->CreateDevice(MakeDevice("robot-b"), kActor));
  ASSERT_OK_AND_ASSIGN(Device a, store_->CreateDevice(MakeDevice("robot-a"), kActor));
  EXPECT_EQ(a.sensor_model, "ICM-20948");
  ASSERT_OK_AND_ASSIGN(Device got, store_->GetDevice("robot-b"));
  EXPECT_EQ(got.id, "robot-b");
  EXPECT_EQ(got.nominal_rate_hz, 200);
  EXPECT_EQ(got.accel_unit, "m/s^2");
  EXPECT_EQ(got.created_at, b.created_at);
  ASSERT_OK_AND_ASSIGN(std::vector<Device> all, store_->ListDevices());
  ASSERT_EQ(all.size(), 2u);
  EXPECT_EQ(all[0].id, "robot-a");
  EXPECT_EQ(all[1].id, "robot-b");

  EXPECT_EQ(store_->CreateDevice(MakeDevice(""), kActor).status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(store_->CreateDevice(MakeDevice("robot-c"), "").status().code(),
            absl::StatusCode::kInvalidArgument);
  EXPECT_EQ(store_->GetDevice("robot-z").status().code(), absl::StatusCode::kNotFound);
}

TEST_P(StoreTest, RegisteringAgainIsANoOpUnlessTheMetadataDiffers) {
  ASSERT_OK_AND_ASSIGN(Device first, store_->CreateDevice(MakeDevice("robot-1"), kActor));
  // Robots register at every boot.
  ASSERT_OK_AND_ASSIGN(Device again, store_->CreateDevice(MakeDevice("robot-1"), "robot-1"));
  EXPECT_EQ(again.created_at, first.created_at);
  EXPECT_EQ(AuditActions(DeviceTarget("robot-1")), std::vector<std::string>{"device.create"});

  Device other = MakeDevice("robot-1");
  other.gyro_unit = "deg/s";
  absl::Status taken = store_->CreateDevice(other, kActor).status();
  EXPECT_EQ(taken.code(), absl::StatusCode::kAlreadyExists);
  EXPECT_THAT(taken.message(), HasSubstr("gyro_unit rad/s, not deg/s"));
}

TEST_P(StoreTest, DevicesPageByIdAndShowTheirActiveVersion) {
  for (const char* id : {"robot-c", "robot-a", "robot-d", "robot-b"}) {
    ASSERT_OK(store_->CreateDevice(MakeDevice(id), kActor).status());
  }
  ASSERT_OK_AND_ASSIGN(std::vector<Device> page1, store_->ListDevices("", 3));
  ASSERT_EQ(page1.size(), 3u);
  EXPECT_EQ(page1[2].id, "robot-c");
  ASSERT_OK_AND_ASSIGN(std::vector<Device> page2, store_->ListDevices(page1.back().id, 3));
  ASSERT_EQ(page2.size(), 1u);
  EXPECT_EQ(page2[0].id, "robot-d");

  EXPECT_EQ(store_->GetDevice("robot-b").value().active_version, 0);
  ASSERT_OK(
      store_->AddVersion(MakeVersion("robot-b", Verdict::kPass, VersionState::kActive), "server")
          .status());
  ASSERT_OK(store_->AddVersion(MakeVersion("robot-b"), "server").status());
  EXPECT_EQ(store_->GetDevice("robot-b").value().active_version, 1);
  EXPECT_EQ(store_->ListDevices().value()[1].active_version, 1);
}

}  // namespace
}  // namespace imucal::storage
