// imucal::sdk from an installed prefix: loads an "imucal-params v1" JSON and applies it.
//   apply_params PARAMS.json < samples   (samples.h has the lines in and out)
#include <cstdio>

#include "formats/params_json.h"
#include "samples.h"
#include "util/file.h"

int main(int argc, char** argv) {
  if (argc != 2) return std::fprintf(stderr, "usage: apply_params PARAMS.json < samples\n"), 2;
  auto text = imucal::ReadFileBytes(argv[1]);
  if (!text.ok()) return std::fprintf(stderr, "%s\n", text.status().ToString().c_str()), 1;
  auto params = imucal::formats::ParamSetFromJson(*text);
  if (!params.ok()) return std::fprintf(stderr, "%s\n", params.status().ToString().c_str()), 1;
  return CorrectStdin(*params);
}
