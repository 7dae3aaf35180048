# Sourced after pre.sh: run from the clean snapshot .dev4/src (the commit under test; the tree has others' work).
R=$PWD
[ -f .dev4/src/jaxcls/perception/weights/pointnet_builtin.msgpack ] || cp jaxcls/perception/weights/*.msgpack .dev4/src/jaxcls/perception/weights/
cd .dev4/src && export PYTHONPATH=/tmp/site:$PWD && ln -sfn /tmp/data data && cat COMMIT
