"""Summarise XLA's log lines (glog format) between PROBE-MARK LOAD-START and LOAD-END: the time attributed to each
source file (until the next line) and the largest gaps. ``python vlogsum.py stderr.txt``"""

import collections
import re
import sys

LINE = re.compile(r"^[IWEF](\d{4}) (\d\d):(\d\d):(\d\d)\.(\d{6})\s+\d+ ([^\]]+)\] ?(.*)")


def main(path: str) -> None:
    inside, last = False, None
    per, count, gaps = collections.Counter(), collections.Counter(), []
    for line in open(path, errors="replace"):
        if "PROBE-MARK LOAD-START" in line or "PROBE-MARK LOAD-END" in line:
            inside, last = "LOAD-START" in line, None
            print(line.strip())
            continue
        match = LINE.match(line) if inside else None
        if not match:
            continue
        seconds = int(match[2]) * 3600 + int(match[3]) * 60 + int(match[4]) + int(match[5]) / 1e6
        source = match[6].split(":")[0]
        if last is not None:
            per[last[1]] += seconds - last[0]
            gaps.append((seconds - last[0], last[2][:200]))
        count[source] += 1
        last = (seconds, source, line.strip())
    print("== time after each source's lines (s), count")
    for source, seconds in per.most_common(40):
        print(f"{seconds:8.3f} {count[source]:7d} {source}")
    print("== largest gaps")
    for seconds, text in sorted(gaps, reverse=True)[:40]:
        print(f"{seconds:8.3f} {text}")


if __name__ == "__main__":
    main(sys.argv[1])
