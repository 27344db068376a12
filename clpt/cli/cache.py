"""`clpt cache`: the kernel build cache shown or cleared."""

from __future__ import annotations


def add_parser(sub):
    p = sub.add_parser("cache", help="show or clear the kernel build cache")
    p.add_argument("--clear", action="store_true")
    p.set_defaults(func=run)
    return p


def run(a) -> int:
    from ..program import cache_dir, cache_limit_bytes, clear_cache

    if a.clear:
        print(f"removed {clear_cache()} cached kernel builds, the tuned settings and the device checks "
              f"from {cache_dir()}")
    else:
        d = cache_dir() / "kernels"
        files = list(d.glob("*.bin")) if d.is_dir() else []
        print(f"{cache_dir()}: {len(files)} cached kernel builds, {sum(f.stat().st_size for f in files) / 1e6:.1f} MB "
              f"(at most {cache_limit_bytes() / 2 ** 20:.0f} MiB, CLPT_CACHE_MB: the least recently used go first)")
    return 0
