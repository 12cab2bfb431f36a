// imucal::sdk_client from an installed prefix: a robot whose server is down boots from its local
// cache. Writes PARAMS.json into the cache CACHE, asks SERVER (one nobody listens on) for the
// active set, boots from the cache, applies it.
//   boot_from_cache PARAMS.json CACHE SERVER < samples   (samples.h has the lines in and out)
#include <cstdio>

#include "absl/time/time.h"
#include "client/sdk/client.h"
#include "client/sdk/param_cache.h"
#include "formats/crc32c.h"
#include "formats/params_json.h"
#include "samples.h"
#include "util/file.h"

int main(int argc, char** argv) {
  using namespace imucal;
  if (argc != 4)
    return std::fprintf(stderr, "usage: boot_from_cache PARAMS.json CACHE SERVER < samples\n"), 2;
  auto text = ReadFileBytes(argv[1]);
  if (!text.ok()) return std::fprintf(stderr, "%s\n", text.status().ToString().c_str()), 1;
  auto params = formats::ParamSetFromJson(*text);
  if (!params.ok()) return std::fprintf(stderr, "%s\n", params.status().ToString().c_str()), 1;
  sdk::StoredParams stored{params->device, params->version, formats::Crc32c(*text), *text};
  if (auto st = sdk::SaveParamCache(argv[2], stored); !st.ok())
    return std::fprintf(stderr, "%s\n", st.ToString().c_str()), 1;

  auto client = sdk::ParamClient::Create(argv[3]);
  if (!client.ok()) return std::fprintf(stderr, "%s\n", client.status().ToString().c_str()), 1;
  auto boot = sdk::LoadOrFetch(*client, params->device, argv[2], absl::Seconds(2));
  if (!boot.ok()) return std::fprintf(stderr, "%s\n", boot.status().ToString().c_str()), 1;
  if (!boot->from_cache) return std::fprintf(stderr, "expected a boot from the cache\n"), 1;
  std::fprintf(stderr, "%s\n", boot->note.c_str());
  return CorrectStdin(boot->loaded.params);
}
