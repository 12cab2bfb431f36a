#include "server/session_hub.h"

#include <utility>

#include "absl/time/clock.h"
#include "core/capture.h"
#include "storage/sample_codec.h"

namespace imucal::server {
namespace {

v1::SessionEvent Stamped() {
  v1::SessionEvent e;
  ToTimestamp(absl::Now(), e.mutable_time());
  return e;
}

}  // namespace

core::OnlineSegmenterOptions SegmenterOptionsFor(const storage::Device& device,
                                                 v1::Protocol protocol) {
  core::OnlineSegmenterOptions opt;
  opt.rate_hz = device.nominal_rate_hz;
  opt.six_face = protocol == v1::PROTOCOL_SIX_FACE;
  if (auto unit = core::ParseAccelUnit(device.accel_unit); unit.ok()) opt.accel_unit = *unit;
  return opt;
}

absl::StatusOr<std::shared_ptr<LiveSession>> SessionHub::Get(std::string_view session_id) {
  {
    std::lock_guard lock(mu_);
    if (auto it = sessions_.find(session_id); it != sessions_.end()) return it->second;
  }
  // Loading decodes the stored batches: outside mu_, then the first one to finish wins.
  absl::StatusOr<std::shared_ptr<LiveSession>> loaded = Load(session_id);
  if (!loaded.ok()) return loaded.status();
  std::lock_guard lock(mu_);
  auto [it, inserted] = sessions_.emplace(std::string(session_id), *std::move(loaded));
  return it->second;
}

int SessionHub::PeekPosesAccepted(std::string_view session_id) {
  std::shared_ptr<LiveSession> s;
  {
    std::lock_guard lock(mu_);
    auto it = sessions_.find(session_id);
    if (it == sessions_.end()) return -1;
    s = it->second;
  }
  std::lock_guard lock(s->mu);
  return s->segmenter->poses_accepted();
}

absl::StatusOr<std::shared_ptr<LiveSession>> SessionHub::Load(std::string_view session_id) {
  absl::StatusOr<storage::Session> session = store_->GetSession(session_id);
  if (!session.ok()) return session.status();
  absl::StatusOr<storage::Device> device = store_->GetDevice(session->device_id);
  if (!device.ok()) return device.status();
  auto live = std::make_shared<LiveSession>();
  live->id = session->id;
  live->device = *device;
  live->protocol = ParseProtocol(session->protocol);
  live->gravity_m_s2 = session->gravity_m_s2;
  live->segmenter =
      std::make_unique<core::OnlineSegmenter>(SegmenterOptionsFor(*device, live->protocol));
  absl::StatusOr<std::vector<storage::SampleBatch>> batches = store_->ReadBatches(session_id);
  if (!batches.ok()) return batches.status();
  std::vector<core::SegmenterEvent> ignored;
  std::vector<storage::ImuSample> samples;
  for (const storage::SampleBatch& b : *batches) {
    samples.clear();
    if (absl::Status s = storage::DecodeSamplesInto(b.payload, &samples); !s.ok()) return s;
    for (const storage::ImuSample& x : samples) {
      live->segmenter->Add(x.t_s, Eigen::Vector3d(x.accel[0], x.accel[1], x.accel[2]),
                           Eigen::Vector3d(x.gyro[0], x.gyro[1], x.gyro[2]), &ignored);
      ignored.clear();
    }
    if (!samples.empty()) live->last_t_s = samples.back().t_s;
    live->last_acked_seq = b.seq;
  }
  live->closed = session->state != storage::SessionState::kOpen &&
                 session->state != storage::SessionState::kSolving;
  return live;
}

void SessionHub::Publish(LiveSession& session, const v1::SessionEvent& event) {
  std::lock_guard lock(session.watchers_mu);
  for (Watcher* w : session.watchers) w->Push(event);
}

void SessionHub::AddWatcher(LiveSession& session, Watcher* watcher) {
  std::lock_guard lock(session.watchers_mu);
  if (session.closed) {
    watcher->Close();
    return;
  }
  session.watchers.push_back(watcher);
}

void SessionHub::RemoveWatcher(LiveSession& session, Watcher* watcher) {
  std::lock_guard lock(session.watchers_mu);
  std::erase(session.watchers, watcher);
}

void SessionHub::CloseSession(LiveSession& session) {
  {
    std::lock_guard lock(session.watchers_mu);
    session.closed = true;
    for (Watcher* w : session.watchers) w->Close();
    session.watchers.clear();
  }
  std::lock_guard lock(mu_);
  sessions_.erase(session.id);
}

void SessionHub::Reopen(LiveSession& session) {
  std::lock_guard lock(session.watchers_mu);
  session.closed = false;
}

v1::SessionEvent SessionHub::NextPoseEvent(const core::NextPoseUpdate& next) {
  v1::SessionEvent e = Stamped();
  v1::NextPose* n = e.mutable_next_pose();
  n->set_instruction(next.instruction);
  n->set_face(next.face);
  n->set_turn_half(next.turn_half);
  return e;
}

v1::SessionEvent SessionHub::ProgressEvent(const LiveSession& session) {
  v1::SessionEvent e = Stamped();
  v1::Progress* p = e.mutable_progress();
  const core::OnlineSegmenter& seg = *session.segmenter;
  p->set_poses_accepted(seg.poses_accepted());
  if (session.protocol == v1::PROTOCOL_SIX_FACE) {
    p->set_poses_wanted(core::OnlineSegmenter::kSixFaceSteps);
    for (const std::string& f : seg.FacesDone()) p->add_faces_done(f);
    for (const std::string& f : seg.FacesPending()) p->add_faces_pending(f);
    p->set_coverage(static_cast<double>(seg.FacesDone().size()) / 6.0);
  }
  return e;
}

std::vector<v1::SessionEvent> SessionHub::ToEvents(
    const LiveSession& session, const std::vector<core::SegmenterEvent>& events) {
  std::vector<v1::SessionEvent> out;
  for (const core::SegmenterEvent& se : events) {
    switch (se.kind) {
      case core::SegmenterEvent::Kind::kStillness: {
        v1::SessionEvent e = Stamped();
        v1::Stillness* s = e.mutable_stillness();
        s->set_still(se.stillness.still);
        s->set_still_for_s(se.stillness.still_for_s);
        s->set_needed_s(se.stillness.needed_s);
        s->set_motion_ratio(se.stillness.motion_ratio);
        out.push_back(std::move(e));
        break;
      }
      case core::SegmenterEvent::Kind::kPose: {
        v1::SessionEvent e = Stamped();
        v1::PoseEvent* p = e.mutable_pose();
        p->set_index(se.pose.index);
        p->set_accepted(se.pose.accepted);
        p->set_reason(se.pose.reason);
        p->set_face(se.pose.face);
        p->set_t_start_s(se.pose.t_start_s);
        p->set_t_end_s(se.pose.t_end_s);
        out.push_back(std::move(e));
        out.push_back(ProgressEvent(session));
        break;
      }
      case core::SegmenterEvent::Kind::kNextPose:
        out.push_back(NextPoseEvent(se.next_pose));
        break;
    }
  }
  return out;
}

}  // namespace imucal::server
