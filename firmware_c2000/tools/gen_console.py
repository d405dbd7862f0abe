#!/usr/bin/env python3
"""Generate the console command table of fw_host from protocols/console.json.

protocols/console.json is the machine-readable form of protocols/console.md (the grammar of
the SCI console). This script writes into the build directory (never committed):

* ``console_gen.h``: ``CON_VERSION``, ``CON_MAX_LINE``, one ``CON_ERR_<NAME>`` per error code,
  the command ids ``CON_CMD_<NAME>`` and the table types;
* ``console_gen.c``: the constant command table (names, usage, summaries, argument kinds).

Usage: gen_console.py CONSOLE_JSON OUT_DIR
"""

from __future__ import annotations

import json
import re
import sys
from pathlib import Path
from typing import Any

from c_codegen import banner, c_string, generate

WORD_RE = re.compile(r"^[a-z][a-z0-9_]*$")
ARG_TYPES = {"param": "CON_ARG_PARAM", "number": "CON_ARG_NUMBER", "choice": "CON_ARG_CHOICE"}
MAX_ARGS = 2


class SpecError(ValueError):
    pass


def usage(cmd: dict[str, Any]) -> str:
    parts = [cmd["name"]]
    for a in cmd["args"]:
        parts.append("|".join(a["choices"]) if a["type"] == "choice" else a["name"])
    return " ".join(parts)


def check(spec: dict[str, Any]) -> None:
    if not isinstance(spec.get("version"), int):
        raise SpecError("version must be an integer")
    if not isinstance(spec.get("max_line"), int) or not 16 <= spec["max_line"] <= 255:
        raise SpecError("max_line must be an integer in 16..255")
    codes = [e["code"] for e in spec["errors"]]
    if codes != list(range(1, len(codes) + 1)):
        raise SpecError("error codes must be 1, 2, 3, ... in order")
    for e in spec["errors"]:
        if not re.match(r"^[A-Z][A-Z0-9_]*$", e["name"]):
            raise SpecError(f"error name {e['name']!r} is not an upper-case identifier")
    names: set[str] = set()
    for cmd in spec["commands"]:
        name = cmd["name"]
        if not WORD_RE.match(name) or name in names:
            raise SpecError(f"command {name!r}: not a lower-case word or a duplicate")
        names.add(name)
        if len(cmd["args"]) > MAX_ARGS:
            raise SpecError(f"command {name!r}: more than {MAX_ARGS} arguments")
        for a in cmd["args"]:
            if a["type"] not in ARG_TYPES:
                raise SpecError(f"command {name!r}: unknown argument type {a['type']!r}")
            if a["type"] == "choice":
                if not a.get("choices") or not all(WORD_RE.match(c) for c in a["choices"]):
                    raise SpecError(f"command {name!r}: choice argument needs lower-case words")


def header(spec: dict[str, Any]) -> str:
    out = [
        *banner("gen_console.py", "protocols/console.json"),
        "#ifndef CONSOLE_GEN_H",
        "#define CONSOLE_GEN_H",
        "",
        f"#define CON_VERSION {spec['version']}",
        f"#define CON_MAX_LINE {spec['max_line']}",
        f"#define CON_ERR_COUNT {len(spec['errors'])}",
    ]
    for e in spec["errors"]:
        out.append(f"#define CON_ERR_{e['name']} {e['code']}")
    out += ["", "typedef enum {"]
    for cmd in spec["commands"]:
        out.append(f"    CON_CMD_{cmd['name'].upper()},")
    out += [
        "    CON_CMD_COUNT",
        "} con_cmd_id_t;",
        "",
        "typedef enum { CON_ARG_PARAM, CON_ARG_NUMBER, CON_ARG_CHOICE } con_arg_type_t;",
        "",
        "typedef struct {",
        "    const char *name;           /* placeholder in the usage text */",
        "    con_arg_type_t type;",
        "    const char *const *choices; /* CON_ARG_CHOICE: the allowed words, index = value */",
        "    int n_choices;",
        "} con_arg_info_t;",
        "",
        "typedef struct {",
        "    con_cmd_id_t id;",
        "    const char *name;",
        "    const char *usage;",
        "    const char *summary;",
        "    int n_args;",
        f"    con_arg_info_t args[{MAX_ARGS}];",
        "} con_cmd_info_t;",
        "",
        "extern const con_cmd_info_t con_commands[CON_CMD_COUNT];",
        "extern const char *const con_error_names[CON_ERR_COUNT + 1]; /* by code; [0] unused */",
        "",
        "#endif",
        "",
    ]
    return "\n".join(out)


def source(spec: dict[str, Any]) -> str:
    out = [
        *banner("gen_console.py", "protocols/console.json"),
        "#include <stddef.h>",
        '#include "console_gen.h"',
        "",
    ]
    for cmd in spec["commands"]:
        for i, a in enumerate(cmd["args"]):
            if a["type"] == "choice":
                words = ", ".join(c_string(c) for c in a["choices"])
                out.append(f"static const char *const choices_{cmd['name']}_{i}[] = {{{words}}};")
    out += ["", "const con_cmd_info_t con_commands[CON_CMD_COUNT] = {"]
    for cmd in spec["commands"]:
        args = []
        for i, a in enumerate(cmd["args"]):
            if a["type"] == "choice":
                ch, n = f"choices_{cmd['name']}_{i}", len(a["choices"])
            else:
                ch, n = "NULL", 0
            args.append(f"{{{c_string(a['name'])}, {ARG_TYPES[a['type']]}, {ch}, {n}}}")
        while len(args) < MAX_ARGS:
            args.append("{NULL, CON_ARG_NUMBER, NULL, 0}")
        out.append(
            f"    {{CON_CMD_{cmd['name'].upper()}, {c_string(cmd['name'])}, "
            f"{c_string(usage(cmd))}, {c_string(cmd['summary'])}, {len(cmd['args'])}, "
            f"{{{', '.join(args)}}}}},"
        )
    out += ["};", "", "const char *const con_error_names[CON_ERR_COUNT + 1] = {", '    "",']
    for e in spec["errors"]:
        out.append(f"    {c_string(e['name'])},")
    out += ["};", ""]
    return "\n".join(out)


def read(spec_path: Path) -> dict[str, Any]:
    """The console's description, checked; any fault as a ValueError naming the file."""
    try:
        spec: dict[str, Any] = json.loads(spec_path.read_text(encoding="utf-8"))
        check(spec)
    except (OSError, ValueError, KeyError, TypeError) as exc:
        raise ValueError(f"{spec_path}: {exc}") from exc
    return spec


def main(argv: list[str]) -> int:
    return generate(argv, __doc__ or "", read, {"console_gen.h": header, "console_gen.c": source})


if __name__ == "__main__":
    sys.exit(main(sys.argv))
