for i in 1 2; do for v in abA abB; do
  (cd /tmp/$v && PYTHONPATH=/tmp/$v timeout 600 python benchmarks/move.py --scenes 2 --moves 5 --rounds 3 --out /tmp/move_${v}_$i.md > /tmp/move_${v}_$i.log 2>&1; echo "$v $i rc $?")
done; done
