"""The work behind `acroboter animate` (acroboter.cli.animate is its command line): `scene` reads a results folder
and computes what each frame shows (pure numpy), `matplotlib_frames` and `mujoco_frames` draw frames, `encode`
writes them to MP4 or GIF. Nothing heavy is imported here: matplotlib, mujoco and imageio load on first use."""
