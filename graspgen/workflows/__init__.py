"""The table builders: each turns records and settings into one Arrow table (scenes, scene grasps, rollouts,
object-centric sets and their placement in scenes, robustness, metrics) or evaluates grasps (`evaluate`).

They stand above the simulation (`graspgen.sim`), the quality maths (`graspgen.quality`) and the record files
(`graspgen.io`), and below the learned scores (`graspgen.learn`) and the pictures (`graspgen.viz`)."""
