export PYTHONPATH=/tmp/site:$PWD PYTHONUNBUFFERED=1
python -X importtime results/warm_start_2026-11-28/probe3.py 2> /tmp/imp.txt | grep -v Warn | head -70
sort -t'|' -k2 -n -r /tmp/imp.txt | head -25
