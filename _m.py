import json, sys, numpy as np, tifffile
d = sys.argv[1]
m = json.load(open(d + "/pack_0000/manifest.json"))
lab = tifffile.imread(d + "/pack_0000/labels.tif")
c = m["pour_checks"]
print("labels", (lab > 0).mean(), "checks", c["packing_fraction"], c["target_reached"], c["max_grain_penetration_voxels"], c["overlap_fraction"], c["compaction"]["knobs"], c["compaction"].get("max_shrink"))
