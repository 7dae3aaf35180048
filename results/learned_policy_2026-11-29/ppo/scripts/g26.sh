# One host (stage first): Table 1 at 1,000 scenes of $SET for classifier $CL ($SRC: its weights), rows $ROWS, the
# oracle on $O scenes, learned weights $W, limited to L s, on $LP local processes (one a GPU), into /tmp/t_$NAME.
# $DS: the dataset overrides (default 1,000 scenes); $SEEDREC (.jsonl or .jsonl.xz) with $SEEDROWS (a grep -E
# pattern): records put into the store first, once (their episodes are then skipped). Tars $OUT/t_$NAME.tgz.
source .dev5/s/pre.sh || exit 1
unset PYTHONDONTWRITEBYTECODE; export PYTHONPYCACHEPREFIX=/tmp/pyc JAXCLS_CACHE_DIR=/tmp/xla
set -f
out=/tmp/t_$NAME; mkdir -p $OUT/r/t_$NAME $out
if [ -n "$SEEDREC" ] && [ ! -e $out/seeded ]; then
  case $SEEDREC in *.xz) xz -dc $SEEDREC;; *) cat $SEEDREC;; esac | grep -E "${SEEDROWS:-.}" > $out/episodes.jsonl
  echo "seeded $(wc -l < $out/episodes.jsonl) records from $SEEDREC"; touch $out/seeded; fi
P=; [ "${LP:-1}" -gt 1 ] && P="--local-processes $LP"
/usr/bin/time -f "table1 $NAME: wall %e s" timeout ${L:-300} python experiments/table1.py $P --config table1_${SET}_scale \
  out_dir=$out scene_chunk=50 "dataset_overrides=[${DS:-num_scenes=1000,out_dir=/tmp/data/$SET}]" "rows=[$ROWS]" \
  oracle_scenes=${O:-0} "classifiers={$CL: \"$SRC\"}" ${W:+nbv.learned.weights=$W} $X > $OUT/r/t_$NAME/t1.log 2>&1
echo "table1 $NAME rc $?"; tr '\r' '\n' < $OUT/r/t_$NAME/t1.log | grep -E "wall|Error|error:|Traceback" | tail -4
grep -E "^\| (InfoGainGR|LearnedGR|Oracle|VisOcclHistGR) |^#### " $out/table.md
cp $out/config.yaml $out/table.md $out/table.csv $out/figure4.png $OUT/r/t_$NAME/ 2>/dev/null
cp $out/process.*.log $OUT/r/t_$NAME/ 2>/dev/null
find $out -maxdepth 1 -name 'episodes*.jsonl' | sort | xargs cat > /tmp/t_$NAME.jsonl  # (all stores, for SEEDREC)
xz -T16 -3 -c /tmp/t_$NAME.jsonl > $OUT/r/t_$NAME/episodes.jsonl.xz
echo "stored $(xz -dc $OUT/r/t_$NAME/episodes.jsonl.xz | wc -l) records"
tar czf $OUT/t_$NAME.tgz -C $OUT/r t_$NAME && rm -rf $OUT/r/t_$NAME
