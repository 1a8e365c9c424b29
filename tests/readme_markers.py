"""Generated blocks in a README: the lines between `<!-- NAME:begin ... -->`
and `<!-- NAME:end -->` markers (the exact spelling is each caller's pattern,
whose first two groups are the name and "begin" or "end"). Shared by
tests/update_tables.py and tests/bench/update_readme.py."""


def marked_blocks(lines, marker):
    """({name: (begin line index, end line index)}, [problem, ...]) for the
    markers of `marker` in `lines`: a begin inside another block, a second
    block of one name, an end without its begin, a begin without its end."""
    blocks, open_name, open_at = {}, None, None
    problems = []
    for i, line in enumerate(lines):
        m = marker.match(line)
        if not m:
            continue
        name, kind = m.group(1), m.group(2)
        if kind == "begin":
            if open_name:
                problems.append(f"line {i + 1}: '{name}:begin' inside '{open_name}' "
                                f"(opened at line {open_at + 1})")
            elif name in blocks:
                problems.append(f"line {i + 1}: a second '{name}' table")
            open_name, open_at = name, i
        else:
            if name != open_name:
                problems.append(f"line {i + 1}: '{name}:end' without its begin")
                continue
            blocks[name] = (open_at, i)
            open_name = None
    if open_name:
        problems.append(f"line {open_at + 1}: '{open_name}:begin' has no end marker")
    return blocks, problems
