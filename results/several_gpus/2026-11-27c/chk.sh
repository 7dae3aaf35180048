NOSCENE=1 source .dev5/s/pre.sh
bash .dev5/s/w.sh $P || exit 1
cd .dev5/src && export PYTHONPATH=/tmp/site:$PWD && cat COMMIT && timeout 200 python gpuchk.py 2>&1 | grep -v Warning | tail -5
