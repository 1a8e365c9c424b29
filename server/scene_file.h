// The scene-file parser lives in the wire library (proto/wire/scene_file.h)
// next to the RPC validation it shares; the server and the client use it
// under this namespace.
#pragma once

#include "proto/wire/scene_file.h"

namespace hapticpd::server {

using wire::CheckSceneConfig;
using wire::EffectFromName;
using wire::EffectName;
using wire::ParseSceneFile;
using wire::ParseSceneJson;
using wire::PdModeName;
using wire::SceneFile;
using wire::SceneFileBody;
using wire::SceneFileError;
using wire::SceneFileProbe;
using wire::SceneHasEffect;

}  // namespace hapticpd::server
