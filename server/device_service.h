// DeviceService of imucal/v1/imucal.proto on the callback API: registering the robots and
// listing them. Handlers validate -> convert -> call the store -> convert -> finish; store
// calls are short transactions (SQLite or PostgreSQL, storage/store.h) run inline.
#ifndef IMUCAL_SERVER_DEVICE_SERVICE_H_
#define IMUCAL_SERVER_DEVICE_SERVICE_H_

#include "grpcpp/grpcpp.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "server/auth.h"
#include "storage/store.h"

namespace imucal::server {

// `auth` checks each caller (server/auth.h): not owned, outlives the service.
class DeviceServiceImpl final : public v1::DeviceService::CallbackService {
 public:
  DeviceServiceImpl(storage::Store* store, Authorizer* auth) : store_(store), auth_(auth) {}
  grpc::ServerUnaryReactor* RegisterDevice(grpc::CallbackServerContext* context,
                                           const v1::RegisterDeviceRequest* request,
                                           v1::Device* response) override;
  grpc::ServerUnaryReactor* GetDevice(grpc::CallbackServerContext* context,
                                      const v1::GetDeviceRequest* request,
                                      v1::Device* response) override;
  grpc::ServerUnaryReactor* ListDevices(grpc::CallbackServerContext* context,
                                        const v1::ListDevicesRequest* request,
                                        v1::ListDevicesResponse* response) override;

 private:
  absl::Status DoRegister(const grpc::CallbackServerContext& context,
                          const v1::RegisterDeviceRequest& request, v1::Device* response);
  storage::Store* store_;
  Authorizer* auth_;
};

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_DEVICE_SERVICE_H_
