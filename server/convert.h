// The wire conversions live in the wire library (proto/wire/convert.h), which
// the client shares; the server uses them under its own namespace.
#pragma once

#include "proto/wire/convert.h"

namespace hapticpd::server {

using wire::FromProto;
using wire::InvalidArgument;
using wire::MeshFromBytes;
using wire::MeshFromInline;
using wire::MeshFromShape;
using wire::NowNs;
using wire::ToProto;
using wire::ValidateId;
using wire::ValidateTwist;

}  // namespace hapticpd::server
