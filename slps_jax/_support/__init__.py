"""What every layer uses and that imports nothing of the package: input checks and the dtype
policy (`checks`), batching helpers, the failure codes and `Solution` (`solution`), progress
and progress bars."""
