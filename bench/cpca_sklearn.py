"""Baseline for `ltbake cpca`: scikit-learn KMeans + one PCA per cluster, on the same rows
with the same K and S, as a user would write it. Prints one JSON line: fit time (s),
relative RMS error ‖X − X̂‖_F / ‖X‖_F in double, and the process's peak RSS.

usage: cpca_sklearn.py ROWS.npy K S [--seed N]
"""
import json
import resource
import sys
import time

import numpy as np
from sklearn.cluster import KMeans
from sklearn.decomposition import PCA

path, k, s = sys.argv[1], int(sys.argv[2]), int(sys.argv[3])
seed = int(sys.argv[sys.argv.index("--seed") + 1]) if "--seed" in sys.argv else 1
t_load = time.perf_counter()
x = np.load(path)  # N × D float32, as ltbake convert writes it
t0 = time.perf_counter()
# n_init=1: one k-means++ start (scikit-learn's 'auto' for k-means++ since 1.4); ltbake
# also starts once from a seeded k-means++.
km = KMeans(n_clusters=k, n_init=1, random_state=seed).fit(x)
labels = km.labels_
t1 = time.perf_counter()
err = 0.0
for c in range(k):
    xc = x[labels == c]
    if len(xc) == 0:
        continue
    n_comp = min(s, len(xc), x.shape[1])
    if n_comp == 0:
        rec = np.broadcast_to(xc.mean(axis=0), xc.shape)
    else:
        pca = PCA(n_components=n_comp, svd_solver="auto", random_state=seed).fit(xc)
        rec = pca.inverse_transform(pca.transform(xc))
    d = xc.astype(np.float64) - rec.astype(np.float64)
    err += float(np.sum(d * d))
t2 = time.perf_counter()
norm = float(np.sum(x.astype(np.float64) ** 2))
print(json.dumps({"kmeans_s": t1 - t0, "pca_s": t2 - t1, "fit_s": t2 - t0, "load_s": t0 - t_load,
                  "relative_rms_error": (err / norm) ** 0.5 if norm > 0 else err ** 0.5,
                  "iterations": int(km.n_iter_),
                  "peak_rss_kib": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss}))
