// Names of gRPC status codes, for messages and logs on both sides of the
// wire ("NOT_FOUND: scene_id: no scene 'x'").
#pragma once

#include <grpcpp/support/status_code_enum.h>

namespace hapticpd::wire {

/// The code's name as gRPC spells it, e.g. "INVALID_ARGUMENT"; "UNKNOWN"
/// for a value that is not a gRPC status code. Takes the code as an int
/// (grpc::StatusCode converts implicitly), so that a number from a foreign
/// peer is never held in the enum outside its range.
const char* StatusCodeName(int code);

}  // namespace hapticpd::wire
