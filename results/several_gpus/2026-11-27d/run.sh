# Sourced after pre.sh: run from the clean snapshot .dev5/src (the commit under test; the tree has others' work).
R=$PWD
[ -f .dev5/src/jaxcls/perception/weights/pointnet_builtin.msgpack ] || cp jaxcls/perception/weights/*.msgpack .dev5/src/jaxcls/perception/weights/
cd .dev5/src && export PYTHONPATH=/tmp/site:$PWD && ln -sfn /tmp/data data && cat COMMIT
