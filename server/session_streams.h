// The streaming calls of SessionService, each a reactor in its own file on the base of
// server/stream_reactor.h. The service's handlers return what these return.
#ifndef IMUCAL_SERVER_SESSION_STREAMS_H_
#define IMUCAL_SERVER_SESSION_STREAMS_H_

#include "grpcpp/grpcpp.h"
#include "imucal/v1/imucal.grpc.pb.h"
#include "server/stream_reactor.h"

namespace imucal::server {

// StreamSamples (ingest_reactor.cc): the robot's batches stored and acknowledged one by one.
grpc::ServerBidiReactor<grpc::ByteBuffer, grpc::ByteBuffer>* StartStreamSamples(
    const StreamEnv& env, grpc::CallbackServerContext* context);

// WatchSession (watch_reactor.cc): a snapshot of the session, then its events.
grpc::ServerWriteReactor<v1::SessionEvent>* StartWatchSession(
    const StreamEnv& env, grpc::CallbackServerContext* context,
    const v1::WatchSessionRequest& request);

// ReadSamples (read_reactor.cc): the session's stored batches, paged out of storage.
grpc::ServerWriteReactor<v1::SampleBatch>* StartReadSamples(const StreamEnv& env,
                                                            grpc::CallbackServerContext* context,
                                                            const v1::ReadSamplesRequest& request);

}  // namespace imucal::server

#endif  // IMUCAL_SERVER_SESSION_STREAMS_H_
