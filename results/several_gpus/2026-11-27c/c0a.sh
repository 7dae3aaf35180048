mkdir -p /tmp/wh && cp .dev5/p1a/*.whl /tmp/wh/ && ls /tmp/wh
