# Call O1..O3: a warp part (P env: .dev4/w.N).
NOSCENE=1 source .dev4/s/pre.sh
bash .dev4/s/w.sh $P
