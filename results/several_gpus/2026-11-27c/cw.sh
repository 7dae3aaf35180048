# Calls 1..: a warp part (P env: .dev5/w.N; LAST env: the last part's name).
NOSCENE=1 source .dev5/s/pre.sh
bash .dev5/s/w.sh $P
