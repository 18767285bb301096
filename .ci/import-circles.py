#!/usr/bin/env python3
"""No import circles between the modules of a crate (ARCHITECTURE.md "No import circles").

The graph: `crate::` paths (use lines, inline paths, intra-doc links), `super::` and
child-module paths, outside `#[cfg(test)]` and plain `//` comments; a module and its own
submodules are one unit. Prints each circle (a strongly connected component) and fails.
Usage: import-circles.py SRC_DIR [MODULE_TO_SKIP ...]"""
import os, re, sys

def modules(src):
    mods = {}
    for root, _, files in os.walk(src):
        for f in files:
            if not f.endswith('.rs'): continue
            p = os.path.join(root, f)
            rel = os.path.relpath(p, src)[:-3]
            parts = rel.split(os.sep)
            if parts[-1] in ('mod', 'lib', 'main'): parts = parts[:-1]
            mods['::'.join(parts)] = p
    return mods

def strip(text):
    # drop comments (doc links are not imports) and everything from #[cfg(test)] on
    i = text.find('#[cfg(test)]')
    if i >= 0: text = text[:i]
    # plain comments are not imports; doc comments (/// and //!) are: their intra-doc links
    # tie the modules' documentation together
    text = re.sub(r'//(?![/!])[^\n]*', '', text)
    return text

def paths(text):
    out = []
    # expand use crate::{a, b::{c, d}} groups
    for m in re.finditer(r'\bcrate::([A-Za-z_][\w:]*)(::\{)?', text):
        base = m.group(1).rstrip(':')
        if m.group(2):
            # read the brace group
            j = m.end(); depth = 1; k = j
            while depth and k < len(text):
                if text[k] == '{': depth += 1
                elif text[k] == '}': depth -= 1
                k += 1
            inner = text[j:k-1]
            for item in re.split(r'[,{}\s]+', inner):
                item = item.strip()
                if not item or item == 'self': out.append(base); continue
                out.append(base + '::' + item.split('::')[0])
        else:
            out.append(base)
    # super:: paths
    return out

def resolve(path, mods):
    parts = path.split('::')
    for n in range(len(parts), 0, -1):
        cand = '::'.join(parts[:n])
        if cand in mods: return cand
    return None

def main(src, exclude):
    mods = modules(src)
    g = {m: set() for m in mods}
    for m, p in mods.items():
        if any(m == e or m.startswith(e + '::') for e in exclude): continue
        text = strip(open(p).read())
        for path in paths(text):
            t = resolve(path, mods)
            if t and t != m and not any(t == e or t.startswith(e + '::') for e in exclude):
                g[m].add(t)
        # a child module named by a relative path (`child::x`, `self::child::x`)
        for child in [c for c in mods if c.startswith(m + '::') and '::' not in c[len(m)+2:]] if m else [c for c in mods if '::' not in c and c]:
            name = child.rsplit('::', 1)[-1]
            if re.search(r'(?<![\w:])(self::)?' + name + r'::', text):
                g[m].add(child)
        # super:: refers to the parent module
        if re.search(r'\bsuper::', text) and '::' in m:
            parent = m.rsplit('::', 1)[0]
            g[m].add(parent)
    # a module and its own submodules are one unit: edges between a module and its
    # ancestors or descendants are not circles between units
    rel = lambda a, b: a.startswith(b + '::') or b.startswith(a + '::')
    for a in g:
        g[a] = {b for b in g[a] if not rel(a, b)}
    # Tarjan
    idx, low, st, on, comps, c = {}, {}, [], set(), [], [0]
    sys.setrecursionlimit(10000)
    def sc(v):
        idx[v] = low[v] = c[0]; c[0] += 1; st.append(v); on.add(v)
        for w in g[v]:
            if w not in idx: sc(w); low[v] = min(low[v], low[w])
            elif w in on: low[v] = min(low[v], idx[w])
        if low[v] == idx[v]:
            comp = []
            while True:
                w = st.pop(); on.discard(w); comp.append(w)
                if w == v: break
            comps.append(comp)
    for v in g:
        if v not in idx: sc(v)
    bad = [sorted(x) for x in comps if len(x) > 1]
    for comp in bad:
        print(src, 'circle:', ' <-> '.join(comp))
        for a in comp:
            print('   ', a, '->', sorted(b for b in g[a] if b in comp))
    if not bad: print(src, ': no import circles', f'({len(mods)} modules)')
    return 1 if bad else 0

if __name__ == '__main__':
    src = sys.argv[1]; exclude = sys.argv[2:]
    sys.exit(main(src, exclude))
