// In-process fakes of SessionService (GetSession, StreamSamples) and ParameterService
// (GetActiveParameters) for the SDK's tests when the real imucald is not needed: they keep the
// protocol's rules (seq 1, 2, 3 without gaps, an ack per durably stored batch, a repeated batch is
// a no-op) in memory, so the tests can check that every sample arrives exactly once.
#ifndef IMUCAL_TESTS_CLIENT_FAKE_SERVICES_H_
#define IMUCAL_TESTS_CLIENT_FAKE_SERVICES_H_

#include <map>
#include <memory>
#include <mutex>
#include <string>
#include <vector>

#include "absl/strings/str_cat.h"
#include "grpcpp/grpcpp.h"
#include "imucal/v1/imucal.grpc.pb.h"

namespace imucal::testing_util {

class FakeSessionService final : public imucal::v1::SessionService::Service {
 public:
  // Adds an open session.
  void AddSession(const std::string& id) {
    std::lock_guard<std::mutex> lock(mu_);
    sessions_[id].set_id(id);
    sessions_[id].set_state(imucal::v1::SESSION_STATE_OPEN);
  }
  // After this many more batches are stored, the stream fails with UNAVAILABLE (once).
  void FailStreamAfter(int batches) {
    std::lock_guard<std::mutex> lock(mu_);
    fail_after_ = batches;
  }
  std::vector<double> StoredTimes(const std::string& id) {
    std::lock_guard<std::mutex> lock(mu_);
    return times_[id];
  }
  std::vector<double> StoredAccel(const std::string& id) {
    std::lock_guard<std::mutex> lock(mu_);
    return accel_[id];
  }
  int streams_opened() {
    std::lock_guard<std::mutex> lock(mu_);
    return streams_;
  }

  grpc::Status GetSession(grpc::ServerContext*, const imucal::v1::GetSessionRequest* request,
                          imucal::v1::Session* response) override {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = sessions_.find(request->session_id());
    if (it == sessions_.end())
      return grpc::Status(grpc::StatusCode::NOT_FOUND, "session " + request->session_id());
    *response = it->second;
    return grpc::Status::OK;
  }

  grpc::Status StreamSamples(
      grpc::ServerContext* context,
      grpc::ServerReaderWriter<imucal::v1::SampleAck, imucal::v1::SampleBatch>* stream) override {
    {
      std::lock_guard<std::mutex> lock(mu_);
      ++streams_;
    }
    imucal::v1::SampleBatch batch;
    std::string id;
    while (stream->Read(&batch)) {
      if (context->IsCancelled()) return grpc::Status::CANCELLED;
      if (!batch.session_id().empty()) id = batch.session_id();
      imucal::v1::SampleAck ack;
      {
        std::lock_guard<std::mutex> lock(mu_);
        auto it = sessions_.find(id);
        if (it == sessions_.end()) return grpc::Status(grpc::StatusCode::NOT_FOUND, "session");
        imucal::v1::Session& s = it->second;
        if (batch.seq() <= s.last_acked_seq()) {
          // A repeat: a no-op (the fake does not compare the content).
        } else if (batch.seq() != s.last_acked_seq() + 1) {
          return grpc::Status(grpc::StatusCode::FAILED_PRECONDITION,
                              absl::StrCat("expected seq ", s.last_acked_seq() + 1));
        } else {
          const int n = batch.t_s_size();
          if (batch.accel_size() != 3 * n || batch.gyro_size() != 3 * n)
            return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, "columns");
          auto& t = times_[id];
          if (n > 0 && !t.empty() && batch.t_s(0) <= t.back())
            return grpc::Status(grpc::StatusCode::INVALID_ARGUMENT, "t_s not increasing");
          t.insert(t.end(), batch.t_s().begin(), batch.t_s().end());
          auto& a = accel_[id];
          a.insert(a.end(), batch.accel().begin(), batch.accel().end());
          s.set_last_acked_seq(batch.seq());
          s.set_samples(s.samples() + n);
          if (fail_after_ > 0 && --fail_after_ == 0)
            return grpc::Status(grpc::StatusCode::UNAVAILABLE, "fake connection drop");
        }
        ack.set_last_acked_seq(s.last_acked_seq());
        ack.set_samples(s.samples());
      }
      if (!stream->Write(ack)) break;
    }
    return grpc::Status::OK;
  }

 private:
  std::mutex mu_;
  std::map<std::string, imucal::v1::Session> sessions_;
  std::map<std::string, std::vector<double>> times_;
  std::map<std::string, std::vector<double>> accel_;
  int fail_after_ = 0;
  int streams_ = 0;
};

class FakeParameterService final : public imucal::v1::ParameterService::Service {
 public:
  void SetActive(const imucal::v1::ParameterSet& set) {
    std::lock_guard<std::mutex> lock(mu_);
    active_[set.device_id()] = set;
  }
  grpc::Status GetActiveParameters(grpc::ServerContext*,
                                   const imucal::v1::GetActiveParametersRequest* request,
                                   imucal::v1::ParameterSet* response) override {
    std::lock_guard<std::mutex> lock(mu_);
    auto it = active_.find(request->device_id());
    if (it == active_.end())
      return grpc::Status(grpc::StatusCode::NOT_FOUND,
                          "device " + request->device_id() + " has no active parameter set");
    *response = it->second;
    if (request->if_not_version() == response->version()) response->clear_json();
    return grpc::Status::OK;
  }

 private:
  std::mutex mu_;
  std::map<std::string, imucal::v1::ParameterSet> active_;
};

// An in-process server on a loopback port the kernel picks.
class FakeServer {
 public:
  explicit FakeServer(std::vector<grpc::Service*> services) {
    grpc::ServerBuilder builder;
    builder.AddListeningPort("127.0.0.1:0", grpc::InsecureServerCredentials(), &port_);
    for (grpc::Service* s : services) builder.RegisterService(s);
    server_ = builder.BuildAndStart();
  }
  ~FakeServer() { server_->Shutdown(); }
  std::string address() const { return absl::StrCat("127.0.0.1:", port_); }

 private:
  int port_ = 0;
  std::unique_ptr<grpc::Server> server_;
};

}  // namespace imucal::testing_util

#endif  // IMUCAL_TESTS_CLIENT_FAKE_SERVICES_H_
