"""Summarise glog lines between PROBE-MARK LOAD-START and LOAD-END: time attributed to each source (until the next line)."""
import re, sys, collections, datetime
pat = re.compile(r"^[IWEF](\d{4}) (\d\d):(\d\d):(\d\d)\.(\d{6})\s+\d+ ([^\]]+)\] ?(.*)")
inside = False; last = None; per = collections.Counter(); cnt = collections.Counter(); gaps = []
for line in open(sys.argv[1], errors="replace"):
    if "PROBE-MARK LOAD-START" in line:
        inside = True; last = None; print(line.strip()); continue
    if "PROBE-MARK LOAD-END" in line:
        inside = False; print(line.strip()); continue
    if not inside: continue
    m = pat.match(line)
    if not m: continue
    ts = int(m[2]) * 3600 + int(m[3]) * 60 + int(m[4]) + int(m[5]) / 1e6
    src = m[6].split(":")[0]
    if last is not None:
        dt = ts - last[0]; per[last[1]] += dt; gaps.append((dt, last[2][:200]))
    cnt[src] += 1; last = (ts, src, line.strip())
print("== time after each source's lines (s), count")
for s, v in per.most_common(40): print(f"{v:8.3f} {cnt[s]:7d} {s}")
print("== largest gaps")
for dt, l in sorted(gaps, reverse=True)[:40]: print(f"{dt:8.3f} {l}")
