cp .dev5/p1b/*.whl /tmp/wh/ && WH=/tmp/wh NOSCENE=1 source .dev5/s/pre.sh
