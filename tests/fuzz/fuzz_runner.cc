#include "tests/fuzz/fuzz_runner.h"

#include <google/protobuf/descriptor.h>
#include <google/protobuf/dynamic_message.h>
#include <google/protobuf/text_format.h>

#include <cstdlib>
#include <sstream>
#include <stdexcept>

#include "libs/runtime/status.h"
#include "tests/fuzz/generic_call.h"
#include "tests/fuzz/request_mutator.h"

namespace picking::testing {
namespace {

using google::protobuf::Message;
using google::protobuf::MethodDescriptor;

constexpr std::size_t kMaxErrorMessageBytes = 1024;
// An answer may come this much after the call's deadline (the time to deliver it).
constexpr std::chrono::milliseconds kDeadlineSlack(3000);

// A method with its seeds parsed into messages of its request type.
struct MethodPlan {
  const MethodDescriptor* method = nullptr;
  std::string path;
  std::vector<std::vector<std::unique_ptr<Message>>> seeds;  // Each a stream of requests.
  std::vector<bool> must_succeed;
  std::chrono::milliseconds deadline{0};
};

// What one fuzzed call sends.
struct FuzzCall {
  const MethodPlan* plan = nullptr;
  GenericCallPlan wire;
  std::string mode;          // How it was made, for the failure message.
  bool parses = true;        // Every request parses as the method's request type.
  std::string request_text;  // Cut, for the failure message.
};

std::unique_ptr<Message> NewRequest(const MethodDescriptor* method) {
  const Message* prototype =
      google::protobuf::MessageFactory::generated_factory()->GetPrototype(method->input_type());
  if (prototype == nullptr) {
    throw std::runtime_error("no generated type for " + method->input_type()->full_name());
  }
  return std::unique_ptr<Message>(prototype->New());
}

std::unique_ptr<Message> ParseSeed(const MethodDescriptor* method, const std::string& text) {
  std::unique_ptr<Message> message = NewRequest(method);
  if (!google::protobuf::TextFormat::ParseFromString(text, message.get())) {
    throw std::runtime_error("seed of " + method->name() + " does not parse: " + text);
  }
  return message;
}

std::vector<MethodPlan> PrepareMethods(const FuzzTarget& target) {
  const google::protobuf::ServiceDescriptor* service =
      google::protobuf::DescriptorPool::generated_pool()->FindServiceByName(target.service);
  if (service == nullptr) throw std::runtime_error("unknown service " + target.service);
  std::vector<MethodPlan> plans;
  for (int i = 0; i < service->method_count(); ++i) {
    MethodPlan plan;
    plan.method = service->method(i);
    plan.path = "/" + service->full_name() + "/" + plan.method->name();
    const auto deadline = target.deadlines.find(plan.method->name());
    plan.deadline = deadline == target.deadlines.end() ? target.default_deadline : deadline->second;
    for (const FuzzSeed& seed : target.seeds) {
      if (seed.method != plan.method->name()) continue;
      std::vector<std::unique_ptr<Message>> stream;
      for (const std::string& text : seed.requests_text) {
        stream.push_back(ParseSeed(plan.method, text));
      }
      plan.seeds.push_back(std::move(stream));
      plan.must_succeed.push_back(seed.must_succeed);
    }
    if (plan.seeds.empty()) {
      plan.seeds.emplace_back();
      plan.seeds.back().push_back(NewRequest(plan.method));
      plan.must_succeed.push_back(false);
    }
    plans.push_back(std::move(plan));
  }
  for (const FuzzSeed& seed : target.seeds) {
    if (service->FindMethodByName(seed.method) == nullptr) {
      throw std::runtime_error(target.service + " has no method " + seed.method);
    }
  }
  return plans;
}

// Stream-level mutations of a client stream: drop, duplicate, reorder, repeat.
std::string MutateStream(RequestMutator& mutator, std::vector<std::unique_ptr<Message>>& stream) {
  const std::size_t n = stream.size();
  const std::size_t at = mutator.Below(n);
  switch (mutator.Below(4)) {
    case 0:
      stream.erase(stream.begin() + static_cast<long>(at));
      return "stream: message " + std::to_string(at) + " dropped";
    case 1:
      stream.insert(stream.begin() + static_cast<long>(at),
                    std::unique_ptr<Message>(stream[at]->New()));
      stream[at]->CopyFrom(*stream[at + 1]);
      return "stream: message " + std::to_string(at) + " duplicated";
    case 2:
      std::swap(stream[at], stream[mutator.Below(n)]);
      return "stream: messages reordered";
    default: {
      const int copies = 200;
      for (int i = 0; i < copies; ++i) {
        stream.push_back(std::unique_ptr<Message>(stream[at]->New()));
        stream.back()->CopyFrom(*stream[at]);
      }
      return "stream: message " + std::to_string(at) + " repeated 200 times";
    }
  }
}

std::vector<std::unique_ptr<Message>> CopyStream(
    const std::vector<std::unique_ptr<Message>>& stream) {
  std::vector<std::unique_ptr<Message>> out;
  for (const auto& message : stream) {
    out.push_back(std::unique_ptr<Message>(message->New()));
    out.back()->CopyFrom(*message);
  }
  return out;
}

// Chooses how to corrupt one call of `plan` and serializes it.
FuzzCall MakeCall(RequestMutator& mutator, const MethodPlan& plan, std::size_t seed_index) {
  FuzzCall call;
  call.plan = &plan;
  call.wire.method_path = plan.path;
  call.wire.deadline = plan.deadline;
  std::vector<std::unique_ptr<Message>> stream = CopyStream(plan.seeds[seed_index]);
  const bool client_streaming = plan.method->client_streaming();
  const std::size_t roll = mutator.Below(100);
  const std::size_t victim = mutator.Below(stream.size());
  std::vector<std::string> wire;
  if (roll < 6) {
    call.mode = "seed unchanged";
  } else if (roll < 72 || (roll < 80 && !client_streaming) ||
             (roll < 93 && !client_streaming && !plan.method->server_streaming())) {
    call.mode = "structured: " + mutator.Mutate(*stream[victim]);
  } else if (roll < 80) {
    call.mode = MutateStream(mutator, stream);
  } else if (roll < 93 && (client_streaming || plan.method->server_streaming())) {
    // Broken streams. A cancelled unary call is not sent: its handler runs to the end
    // anyway, at a moment the client cannot know, which no later check could tell apart.
    call.mode = "cancelled";
    call.wire.cancel_after_writes = static_cast<int>(mutator.Below(stream.size() + 1));
    if (plan.method->server_streaming()) call.wire.cancel_after_reads = 1;
  }
  for (const auto& message : stream) wire.push_back(message->SerializeAsString());
  if (roll >= 93 && roll < 97) {
    call.mode = "bytes mutated";
    wire[victim] = mutator.MutateBytes(wire[victim]);
  } else if (roll >= 97) {
    call.mode = "random bytes";
    wire[victim] = mutator.RandomBytes(512);
  }
  std::unique_ptr<Message> probe = NewRequest(plan.method);
  for (const std::string& bytes : wire) call.parses = call.parses && probe->ParseFromString(bytes);
  call.request_text =
      stream.empty() ? ""
                     : runtime::CutMessage(
                           stream[std::min(victim, stream.size() - 1)]->ShortDebugString(), 600);
  call.wire.requests = std::move(wire);
  return call;
}

bool IsRefusal(grpc::StatusCode code) {
  switch (code) {
    case grpc::StatusCode::INVALID_ARGUMENT:
    case grpc::StatusCode::NOT_FOUND:
    case grpc::StatusCode::FAILED_PRECONDITION:
    case grpc::StatusCode::OUT_OF_RANGE:
    case grpc::StatusCode::RESOURCE_EXHAUSTED:
    case grpc::StatusCode::UNIMPLEMENTED:
    case grpc::StatusCode::ALREADY_EXISTS:
    case grpc::StatusCode::PERMISSION_DENIED:
    case grpc::StatusCode::INTERNAL:  // Only allowed for bytes that do not parse.
      return true;
    default:
      return false;
  }
}

// What is wrong with the answer to `call`, or "" if nothing.
std::string CheckAnswer(const FuzzCall& call, const GenericCallResult& result) {
  const grpc::StatusCode code = result.status.error_code();
  if (result.hung) return "the call hung past its deadline";
  if (result.elapsed > call.wire.deadline + kDeadlineSlack) {
    return "answered after " + std::to_string(result.elapsed.count()) + " ms, deadline " +
           std::to_string(call.wire.deadline.count()) + " ms";
  }
  if (code == grpc::StatusCode::UNKNOWN) return "UNKNOWN for client input";
  if (code == grpc::StatusCode::INTERNAL && call.parses) return "INTERNAL for client input";
  if (result.status.error_message().size() > kMaxErrorMessageBytes) {
    return "error message of " + std::to_string(result.status.error_message().size()) + " bytes";
  }
  if (result.status.error_message().find("metadata size exceeds") != std::string::npos) {
    return "the real status was lost to the metadata size limit";
  }
  return "";
}

void RecordFailure(FuzzReport& report, int index, const FuzzCall& call,
                   const GenericCallResult& result, const std::string& what) {
  ++report.failure_count;
  if (report.failures.size() >= 20) return;
  std::ostringstream line;
  line << "call " << index << " " << call.plan->method->name() << " ("
       << runtime::CutMessage(call.mode, 200) << "): " << what << "; status "
       << runtime::StatusCodeName(result.status.error_code()) << " '"
       << runtime::CutMessage(result.status.error_message(), 300) << "' after "
       << result.elapsed.count() << " ms; request: " << call.request_text;
  report.failures.push_back(line.str());
}

// One call: send it, check the answer, the server's life and, when `check_truth`, the truth.
// Sets `*unfinished` when the call ended by cancellation or deadline: the client has its
// status at once, but the server may still be finishing the call, so the next call's truth
// snapshot could catch that work and is not compared.
bool RunOne(const FuzzTarget& target, const FuzzCall& call, int index, bool check_truth,
            FuzzReport& report, bool* unfinished) {
  const bool compare = target.truth && check_truth;
  const std::string truth_before = compare ? target.truth() : "";
  const GenericCallResult result = GenericCall(target.channel, call.wire);
  const std::string method = call.plan->method->name();
  ++report.calls;
  ++report.codes[method][runtime::StatusCodeName(result.status.error_code())];
  report.slowest_ms[method] = std::max<long>(report.slowest_ms[method], result.elapsed.count());
  if (target.alive && !target.alive()) {
    RecordFailure(report, index, call, result, "the server died");
    return false;
  }
  if (std::string problem = CheckAnswer(call, result); !problem.empty()) {
    RecordFailure(report, index, call, result, problem);
  }
  const grpc::StatusCode code = result.status.error_code();
  *unfinished = code == grpc::StatusCode::CANCELLED || code == grpc::StatusCode::DEADLINE_EXCEEDED;
  if (compare && IsRefusal(code) && target.truth() != truth_before) {
    RecordFailure(
        report, index, call, result,
        "a refused call changed the truth snapshot: " + truth_before + " -> " + target.truth());
  }
  if (target.restore) target.restore();
  return true;
}

// Every seed marked must_succeed, sent as it is, answers OK.
void CheckSeeds(const FuzzTarget& target, const std::vector<MethodPlan>& plans,
                FuzzReport& report) {
  for (const MethodPlan& plan : plans) {
    for (std::size_t s = 0; s < plan.seeds.size(); ++s) {
      if (!plan.must_succeed[s]) continue;
      FuzzCall call;
      call.plan = &plan;
      call.mode = "seed check";
      call.wire.method_path = plan.path;
      call.wire.deadline = plan.deadline;
      for (const auto& message : plan.seeds[s]) {
        call.wire.requests.push_back(message->SerializeAsString());
      }
      call.request_text = runtime::CutMessage(plan.seeds[s].front()->ShortDebugString(), 600);
      const GenericCallResult result = GenericCall(target.channel, call.wire);
      if (!result.status.ok()) RecordFailure(report, -1, call, result, "a valid seed failed");
      if (target.restore) target.restore();
    }
  }
}

}  // namespace

FuzzOptions FuzzOptionsFromEnvironment(int default_calls) {
  FuzzOptions options;
  options.calls = default_calls;
  if (const char* calls = std::getenv("PICKING_FUZZ_CALLS")) options.calls = std::atoi(calls);
  if (const char* seed = std::getenv("PICKING_FUZZ_SEED")) {
    options.seed = std::strtoull(seed, nullptr, 10);
  }
  return options;
}

std::string FuzzReport::Summary() const {
  std::ostringstream out;
  out << calls << " calls, " << failure_count << " failures\n";
  for (const auto& [method, counts] : codes) {
    out << "  " << method << ":";
    for (const auto& [code, count] : counts) out << " " << code << " " << count;
    out << " (slowest " << slowest_ms.at(method) << " ms)\n";
  }
  for (const std::string& failure : failures) out << "  FAILURE " << failure << "\n";
  return out.str();
}

FuzzReport RunFuzz(const FuzzTarget& target, const FuzzOptions& options) {
  const std::vector<MethodPlan> plans = PrepareMethods(target);
  FuzzReport report;
  CheckSeeds(target, plans, report);
  RequestMutator mutator(options.seed);
  mutator.AddDictionary(target.dictionary);
  std::vector<std::size_t> lottery;  // Method indices, each as often as its weight.
  for (std::size_t i = 0; i < plans.size(); ++i) {
    const auto weight = target.weights.find(plans[i].method->name());
    const int tickets = weight == target.weights.end() ? 1 : weight->second;
    for (int t = 0; t < tickets; ++t) lottery.push_back(i);
  }
  bool check_truth = true, unfinished = false;
  for (int i = 0; i < options.calls; ++i) {
    const MethodPlan& plan = plans[lottery[mutator.Below(lottery.size())]];
    const FuzzCall call = MakeCall(mutator, plan, mutator.Below(plan.seeds.size()));
    if (!RunOne(target, call, i, check_truth, report, &unfinished)) break;
    check_truth = !unfinished;
    if ((i + 1) % options.health_every == 0 &&
        !HealthServing(target.channel, std::chrono::seconds(5))) {
      ++report.failure_count;
      report.failures.push_back("after call " + std::to_string(i) +
                                ": the health check did not answer SERVING within 5 s");
    }
  }
  return report;
}

}  // namespace picking::testing
