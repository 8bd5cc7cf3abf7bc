#include "tests/fuzz/generic_call.h"

#include <grpcpp/client_context.h>
#include <grpcpp/completion_queue.h>
#include <grpcpp/generic/generic_stub.h>
#include <grpcpp/support/byte_buffer.h>

namespace picking::testing {
namespace {

using Clock = std::chrono::steady_clock;
using WallClock = std::chrono::system_clock;  // gRPC deadlines are wall-clock times.

// How long past the call's deadline an operation may take before the call counts as hung.
constexpr std::chrono::seconds kHangGrace(20);

// The completion queue of one call, one operation in flight at a time.
class CallQueue {
 public:
  explicit CallQueue(WallClock::time_point give_up) : give_up_(give_up) {}
  ~CallQueue() {
    queue_.Shutdown();
    void* tag = nullptr;
    bool ok = false;
    while (queue_.Next(&tag, &ok)) {
    }
  }
  grpc::CompletionQueue* get() { return &queue_; }

  /// Waits for the operation just started. Returns its `ok`; sets `hung` (and cancels the
  /// call, then waits for the cancellation) if it does not complete before `give_up`.
  bool Wait(grpc::ClientContext& context, bool* hung) {
    void* tag = nullptr;
    bool ok = false;
    const auto status = queue_.AsyncNext(&tag, &ok, give_up_);
    if (status == grpc::CompletionQueue::GOT_EVENT) return ok;
    *hung = true;
    context.TryCancel();
    queue_.Next(&tag, &ok);
    return false;
  }

 private:
  grpc::CompletionQueue queue_;
  WallClock::time_point give_up_;
};

grpc::ByteBuffer ToBuffer(const std::string& bytes) {
  grpc::Slice slice(bytes);
  return grpc::ByteBuffer(&slice, 1);
}

std::string FromBuffer(const grpc::ByteBuffer& buffer) {
  std::vector<grpc::Slice> slices;
  std::string out;
  if (!buffer.Dump(&slices).ok()) return out;
  for (const grpc::Slice& slice : slices) {
    out.append(reinterpret_cast<const char*>(slice.begin()), slice.size());
  }
  return out;
}

}  // namespace

GenericCallResult GenericCall(const std::shared_ptr<grpc::Channel>& channel,
                              const GenericCallPlan& plan) {
  GenericCallResult result;
  const Clock::time_point start = Clock::now();
  grpc::ClientContext context;
  const WallClock::time_point deadline = WallClock::now() + plan.deadline;
  context.set_deadline(deadline);
  CallQueue queue(deadline + kHangGrace);
  grpc::GenericStub stub(channel);
  std::unique_ptr<grpc::GenericClientAsyncReaderWriter> call =
      stub.PrepareCall(&context, plan.method_path, queue.get());
  void* const tag = &result;
  call->StartCall(tag);
  bool open = queue.Wait(context, &result.hung);
  int writes = 0;
  for (const std::string& request : plan.requests) {
    if (!open) break;
    if (writes == plan.cancel_after_writes) context.TryCancel();
    call->Write(ToBuffer(request), tag);
    open = queue.Wait(context, &result.hung);
    ++writes;
  }
  if (writes == plan.cancel_after_writes) context.TryCancel();
  if (open) {
    call->WritesDone(tag);
    queue.Wait(context, &result.hung);
  }
  // Read every response; a failed write still leaves the responses and status to collect.
  while (!result.hung) {
    grpc::ByteBuffer response;
    call->Read(&response, tag);
    if (!queue.Wait(context, &result.hung)) break;
    if (result.responses == 0) result.first_response = FromBuffer(response);
    ++result.responses;
    if (result.responses == plan.cancel_after_reads) context.TryCancel();
  }
  if (!result.hung) {
    call->Finish(&result.status, tag);
    queue.Wait(context, &result.hung);
  }
  if (result.hung) result.status = grpc::Status(grpc::StatusCode::CANCELLED, "hung");
  result.elapsed = std::chrono::duration_cast<std::chrono::milliseconds>(Clock::now() - start);
  return result;
}

bool HealthServing(const std::shared_ptr<grpc::Channel>& channel,
                   std::chrono::milliseconds timeout) {
  GenericCallPlan plan;
  plan.method_path = "/grpc.health.v1.Health/Check";
  plan.requests = {""};  // HealthCheckRequest{service: ""}.
  plan.deadline = timeout;
  const GenericCallResult result = GenericCall(channel, plan);
  // HealthCheckResponse{status: SERVING (1)} is field 1, varint 1.
  return result.status.ok() && result.first_response == std::string("\x08\x01", 2);
}

}  // namespace picking::testing
