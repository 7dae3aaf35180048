# Call O0: CPU wheels (carry .dev4/p) and the first warp part.
NOSCENE=1 source .dev4/s/pre.sh
python -c "import mujoco, trimesh, omegaconf; print('cpu wheels ok')"
