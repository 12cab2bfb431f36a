#include "client/cli/command_table.h"

#include <cstdio>
#include <cstdlib>
#include <iterator>
#include <map>

#include "client/cli/export_flags.h"
#include "client/cli/import_flags.h"
#include "util/str_util.h"

namespace imucal::cli {
namespace {

// The words that work without a server (calibrate, apply, simulate, noise, demo, export), with
// the server's twins of `demo` and `export`, in the order `imucal help` lists them.
std::vector<CommandSpec> OfflineCommandSpecs() {
  const std::set<std::string> help = {"help"};
  return {
      {.id = "calibrate",
       .word = "calibrate",
       .summary = "calibrate accelerometer and gyroscope from a capture",
       .positional_files = true,
       .valued =
           WithImportValuedFlags({"format", "protocol", "gravity", "accel-unit", "gyro-unit",
                                  "device", "seed", "out", "params-out", "plots", "sensor-class"}),
       .switches = WithImportSwitches(
           {"json", "no-bsas", "no-heldout", "no-effects", "apply-time-effects", "help"})},
      {.id = "apply",
       .word = "apply",
       .summary = "apply a parameter set to a capture",
       .positional_files = true,
       .valued = WithImportValuedFlags({"params", "format", "accel-unit", "gyro-unit"}),
       .switches = WithImportSwitches(help)},
      {.id = "simulate",
       .word = "simulate",
       .summary = "write a simulated capture with known truth",
       .valued = {"out", "protocol", "seed", "rate", "extra-poses", "free-poses", "accel-noise",
                  "gyro-noise", "accel-step", "gyro-step", "accel-unit", "gyro-unit", "floor-tilt",
                  "turn-error", "effect", "truth"},
       .switches = {"no-temperature", "botch-turn", "help"}},
      {.id = "noise",
       .word = "noise",
       .summary = "noise figures (N, B, K) of a rest recording or a stored session",
       .positional_files = true,
       .server = true,  // --session S reads a stored session (noise_session.cc)
       .valued = WithImportValuedFlags({"format", "accel-unit", "gyro-unit", "gravity", "device",
                                        "params", "out", "rostopic", "session", "server"}),
       .switches = WithImportSwitches({"json", "help"})},
      {.id = "learn",
       .word = "learn",
       .summary = "learn the gyro's dynamic block from recordings with a reference orientation",
       .valued = {"train", "test", "params", "out", "plots"},
       .switches = {"json", "help"}},
      {.id = "demo",
       .word = "demo",
       .summary = "simulate, calibrate, apply: the error before and after",
       .valued = {"out-dir", "seed", "extra-poses"},
       .switches = {"no-bsas", "help"}},
      {.id = "demo-server",
       .word = "demo",
       .summary = "the demo through the service (with --server)",
       .server = true,
       .valued = {"server", "seed", "device", "robot-token-file"},
       .switches = {"botch-turn", "help"}},
      {.id = "export-file",
       .word = "export",
       .summary = "a parameter set as json, kalibr, kalibr-intrinsics or openvins",
       .valued = WithExportValuedFlags({"params", "format", "out", "server"}),
       .switches = help},
      {.id = "export-server",
       .word = "export",
       .summary = "a stored parameter version as json, kalibr, kalibr-intrinsics or openvins",
       .server = true,
       .valued = WithExportValuedFlags({"server", "device", "version", "format", "out"}),
       .switches = help},
  };
}

// The words that need the server, in the order `imucal help` lists them.
std::vector<CommandSpec> ServerCommandSpecs() {
  return {
      {.id = "devices",
       .word = "devices",
       .summary = "list, register or show devices",
       .actions = {"register", "get"},
       .server = true,
       .valued = {"server", "sensor-model", "rate", "accel-unit", "gyro-unit"},
       .switches = {"json", "help"}},
      {.id = "session",
       .word = "session",
       .summary = "calibration sessions",
       .actions = {"start", "list", "show", "poses", "cancel"},
       .server = true,
       .valued = {"server", "device", "protocol", "state", "gravity"},
       .switches = {"json", "help"}},
      {.id = "upload",
       .word = "upload",
       .summary = "stream a capture into a session (resumes)",
       .positional_files = true,
       .server = true,
       .valued =
           WithImportValuedFlags({"server", "device", "session", "protocol", "format", "accel-unit",
                                  "gyro-unit", "batch", "pace", "seed", "timeout"}),
       .switches = WithImportSwitches({"solve", "json", "help"})},
      {.id = "guide",
       .word = "guide",
       .summary = "live guidance through a calibration capture",
       .server = true,
       .valued = {"server", "device", "session", "protocol", "seed", "reconnects"},
       .switches = {"no-solve", "help"}},
      {.id = "solve",
       .word = "solve",
       .summary = "solve a session",
       .server = true,
       .valued = {"server", "session", "seed", "timeout"},
       .switches = {"wait", "force", "json", "help"}},
      {.id = "report",
       .word = "report",
       .summary = "the latest solve's report",
       .server = true,
       .valued = {"server", "session", "out"},
       .switches = {"json", "help"}},
      {.id = "params",
       .word = "params",
       .summary = "parameter versions of a device",
       .actions = {"get", "list", "promote", "rollback", "upload"},
       .server = true,
       .valued = {"server", "device", "version", "to", "reason", "file"},
       .switches = {"json", "help"}},
      {.id = "admin",
       .word = "admin",
       .summary = "API tokens (admin role)",
       .actions = {"token"},
       .server = true,
       .valued = {"server", "role", "device", "label", "out"},
       .switches = {"json", "all", "help"}},
  };
}

std::vector<CommandSpec> BuildTable() {
  std::vector<CommandSpec> table = OfflineCommandSpecs();
  std::vector<CommandSpec> server = ServerCommandSpecs();
  table.insert(table.end(), std::make_move_iterator(server.begin()),
               std::make_move_iterator(server.end()));
  return table;
}

// What the shell offers for one command word: the union over the ids that share it.
struct WordFlags {
  std::set<std::string> valued, all;
  std::vector<std::string_view> actions;
  bool files = false;
};

std::map<std::string_view, WordFlags> ByWord() {
  std::map<std::string_view, WordFlags> words;
  for (const CommandSpec& c : CommandTable()) {
    WordFlags& w = words[c.word];
    for (const std::string& f : c.valued) w.valued.insert("--" + f);
    for (const std::string& f : c.switches) w.all.insert("--" + f);
    if (c.server) {
      for (const std::string& f : ConnectionFlags()) w.valued.insert("--" + f);
    }
    w.all.insert(w.valued.begin(), w.valued.end());
    if (w.actions.empty()) w.actions = c.actions;
    w.files |= c.positional_files;
  }
  words["help"].actions = [] {
    std::vector<std::string_view> all;
    for (const CommandSpec& c : CommandTable())
      if (all.empty() || all.back() != c.word) all.push_back(c.word);
    return all;
  }();
  words["completion"].actions = {"bash", "zsh"};
  return words;
}

// The flags that take a value before the command word (imucal --server ADDR COMMAND ...).
constexpr std::string_view kGlobalValued =
    "--server --token --token-file --ca-cert --tls-server-name";

}  // namespace

const std::vector<CommandSpec>& CommandTable() {
  static const std::vector<CommandSpec>* table = new std::vector<CommandSpec>(BuildTable());
  return *table;
}

const CommandSpec& CommandById(std::string_view id) {
  for (const CommandSpec& c : CommandTable())
    if (c.id == id) return c;
  std::fprintf(stderr, "imucal: internal error: no command '%.*s' in the table\n",
               static_cast<int>(id.size()), id.data());
  std::abort();
}

absl::StatusOr<Args> ParseCommandFlags(std::string_view id, const std::vector<std::string>& argv) {
  const CommandSpec& c = CommandById(id);
  return Args::Parse(argv, c.valued, c.switches);
}

std::string BashCompletion() {
  std::string words, cases;
  for (const auto& [word, w] : ByWord()) {
    AppendTo(&words, words.empty() ? "" : " ", word);
    AppendTo(&cases, "    ", word, ")\n      flags=\"", Join(w.all, " "), "\"\n      valued=\"",
             Join(w.valued, " "), "\"\n      actions=\"", Join(w.actions, " "), "\"\n      files=",
             w.files ? "1" : "", " ;;\n");
  }
  return Cat(
      "# bash completion for imucal: generated by `imucal completion bash` from the CLI's own\n"
      "# flag table (client/cli/command_table.cc). Installed by deploy/install.sh.\n"
      "_imucal() {\n"
      "  local cur=${COMP_WORDS[COMP_CWORD]} prev=${COMP_WORDS[COMP_CWORD-1]}\n"
      "  local i word=\n"
      "  # The command word: the first word that is neither a flag nor a flag's value.\n"
      "  for ((i = 1; i < COMP_CWORD; i++)); do\n"
      "    case \" ",
      kGlobalValued,
      " \" in\n"
      "      *\" ${COMP_WORDS[i]} \"*) ((i++)); continue ;;\n"
      "    esac\n"
      "    [[ ${COMP_WORDS[i]} == -* ]] && continue\n"
      "    word=${COMP_WORDS[i]}\n"
      "    break\n"
      "  done\n"
      "  if [[ -z $word ]]; then\n"
      "    if [[ \" ",
      kGlobalValued,
      " \" == *\" $prev \"* ]]; then return; fi\n"
      "    if [[ $cur == -* ]]; then\n"
      "      COMPREPLY=($(compgen -W \"",
      kGlobalValued,
      " --help --version\" -- \"$cur\"))\n"
      "    else\n"
      "      COMPREPLY=($(compgen -W \"",
      words,
      "\" -- \"$cur\"))\n"
      "    fi\n"
      "    return\n"
      "  fi\n"
      "  local flags= valued= actions= files=\n"
      "  case $word in\n",
      cases,
      "  esac\n"
      "  # The value of a flag: a file name, the likeliest kind.\n"
      "  if [[ -n $prev && \" $valued \" == *\" $prev \"* ]]; then\n"
      "    COMPREPLY=($(compgen -f -- \"$cur\"))\n"
      "    return\n"
      "  fi\n"
      "  if [[ $cur == -* ]]; then\n"
      "    COMPREPLY=($(compgen -W \"$flags\" -- \"$cur\"))\n"
      "  elif [[ -n $actions && $i -eq $((COMP_CWORD - 1)) ]]; then\n"
      "    COMPREPLY=($(compgen -W \"$actions\" -- \"$cur\"))\n"
      "  elif [[ -n $files ]]; then\n"
      "    COMPREPLY=($(compgen -f -- \"$cur\"))\n"
      "  fi\n"
      "}\n"
      "complete -o filenames -F _imucal imucal\n");
}

std::string ZshCompletion() {
  std::string commands, cases;
  for (const auto& [word, w] : ByWord()) {
    std::string_view summary = word == "help"         ? "the help of a command"
                               : word == "completion" ? "a completion script (bash, zsh)"
                                                      : "";
    for (const CommandSpec& c : CommandTable()) {
      if (c.word == word && summary.empty()) summary = c.summary;
    }
    std::string quoted(summary);
    for (size_t at = quoted.find('\''); at != std::string::npos; at = quoted.find('\'', at + 4)) {
      quoted.replace(at, 1, "'\\''");
    }
    AppendTo(&commands, "    '", word, ":", quoted, "'\n");
    AppendTo(&cases, "    ", word, ")\n      flags=(", Join(w.all, " "), ")\n      valued=(",
             Join(w.valued, " "), ")\n      actions=(", Join(w.actions, " "), ")\n      files=",
             w.files ? 1 : 0, " ;;\n");
  }
  return Cat(
      "#compdef imucal\n"
      "# zsh completion for imucal: generated by `imucal completion zsh` from the CLI's own flag\n"
      "# table (client/cli/command_table.cc). Installed by deploy/install.sh.\n"
      "_imucal() {\n"
      "  local -a commands flags valued actions global\n"
      "  local word= i files=0\n"
      "  global=(",
      kGlobalValued,
      ")\n"
      "  commands=(\n",
      commands,
      "  )\n"
      "  for ((i = 2; i < CURRENT; i++)); do\n"
      "    if (( ${global[(Ie)$words[i]]} )); then (( i++ )); continue; fi\n"
      "    [[ $words[i] == -* ]] && continue\n"
      "    word=$words[i]\n"
      "    break\n"
      "  done\n"
      "  if [[ -z $word ]]; then\n"
      "    (( ${global[(Ie)$words[CURRENT-1]]} )) && return\n"
      "    if [[ $PREFIX == -* ]]; then\n"
      "      compadd -- $global --help --version\n"
      "    else\n"
      "      _describe -t commands 'imucal command' commands\n"
      "    fi\n"
      "    return\n"
      "  fi\n"
      "  case $word in\n",
      cases,
      "  esac\n"
      "  if (( ${valued[(Ie)$words[CURRENT-1]]} )); then\n"
      "    _files\n"
      "  elif [[ $PREFIX == -* ]]; then\n"
      "    compadd -- $flags\n"
      "  elif (( $#actions && i == CURRENT - 1 )); then\n"
      "    compadd -- $actions\n"
      "  elif (( files )); then\n"
      "    _files\n"
      "  fi\n"
      "}\n"
      "_imucal \"$@\"\n");
}

}  // namespace imucal::cli
