# Call 0: the CPU-path wheels (carry .wheels/p1).
NOSCENE=1 source .dev5/s/pre.sh
