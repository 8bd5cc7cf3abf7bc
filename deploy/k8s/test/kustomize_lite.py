#!/usr/bin/env python3
"""Renders a kustomization offline, the part of kustomize that deploy/k8s uses.

The manifests are written for `kubectl apply -k` (kustomize v4 or later, kubectl 1.21+).
The test renders them with this module so that it needs nothing beyond Debian's python3
and python3-yaml (Debian 12's kubectl is 1.20, whose kustomize v2 renders the base but
refuses the overlays' `patches`); where a real kustomize is at hand the test renders with it too and requires
the same objects (deploy/k8s/test/validate.py).

What it does, as kustomize does it:
  - resources: YAML files (any number of documents) and folders holding a kustomization,
    each rendered on its own first;
  - configMapGenerator / secretGenerator with `files` (key = the file's name, or KEY=FILE)
    and `literals`, the name suffixed with kustomize's content hash, and every reference to
    the generated name in a pod template (volumes, projected volumes, env, envFrom) made to
    the suffixed one when the referring object is in the same namespace;
  - namespace: set on every object that is not cluster-scoped;
  - patches: JSON patches (RFC 6902), from `path` or inline `patch`, applied to each object
    its `target` selects (group, version, kind, name, namespace as anchored regular
    expressions; labelSelector as key=value,...).

Anything else in a kustomization (strategic-merge patches, images, labels, name prefixes,
...) is refused with an error naming it, rather than rendered wrong.

  python3 kustomize_lite.py DIR    # prints the rendered objects as YAML documents
"""
import base64
import copy
import hashlib
import json
import os
import re
import sys

import yaml

KUSTOMIZATION_FILES = ("kustomization.yaml", "kustomization.yml", "Kustomization")
SUPPORTED_FIELDS = {"apiVersion", "kind", "namespace", "resources", "configMapGenerator",
                    "secretGenerator", "patches"}
GENERATOR_FIELDS = {"name", "files", "literals", "type"}
PATCH_FIELDS = {"path", "patch", "target"}
TARGET_FIELDS = {"group", "version", "kind", "name", "namespace", "labelSelector"}

# Kinds without a namespace (those a picking deployment could plausibly contain).
CLUSTER_SCOPED = {"Namespace", "ClusterRole", "ClusterRoleBinding", "PersistentVolume",
                  "StorageClass", "CustomResourceDefinition", "PriorityClass",
                  "MutatingWebhookConfiguration", "ValidatingWebhookConfiguration",
                  "IngressClass", "RuntimeClass", "CSIDriver", "VolumeSnapshotClass"}

# kustomize's legacy output order (its default): these kinds first, in this order ...
ORDER_FIRST = ["Namespace", "ResourceQuota", "StorageClass", "CustomResourceDefinition",
               "ServiceAccount", "PodSecurityPolicy", "Role", "ClusterRole", "RoleBinding",
               "ClusterRoleBinding", "ConfigMap", "Secret", "Endpoints", "Service",
               "LimitRange", "PriorityClass", "PersistentVolume", "PersistentVolumeClaim",
               "Deployment", "StatefulSet", "CronJob", "PodDisruptionBudget"]
# ... these last, every other kind between.
ORDER_LAST = ["MutatingWebhookConfiguration", "ValidatingWebhookConfiguration"]

POD_TEMPLATE_KINDS = {"Deployment", "StatefulSet", "DaemonSet", "ReplicaSet", "Job"}


class KustomizeError(Exception):
    pass


class Generated:
    """A generated ConfigMap or Secret: its name before and after the hash suffix."""

    def __init__(self, kind, original, name):
        self.kind, self.original, self.name = kind, original, name
        self.obj = None  # set by the caller


def _load_yaml_documents(path):
    with open(path, encoding="utf-8") as f:
        try:
            docs = [d for d in yaml.safe_load_all(f) if d is not None]
        except yaml.YAMLError as e:
            raise KustomizeError(f"{path}: {e}") from e
    for d in docs:
        if not isinstance(d, dict) or "kind" not in d or "apiVersion" not in d:
            raise KustomizeError(f"{path}: a document without apiVersion and kind")
        if not isinstance(d.get("metadata"), dict) or not d["metadata"].get("name"):
            raise KustomizeError(f"{path}: a {d['kind']} without metadata.name")
    return docs


def _find_kustomization(directory):
    for name in KUSTOMIZATION_FILES:
        path = os.path.join(directory, name)
        if os.path.isfile(path):
            return path
    raise KustomizeError(f"{directory}: no kustomization.yaml")


# --- kustomize's content hash (api/hasher): sha256 of the JSON encoding (Go's json.Marshal,
# keys sorted, <, > and & escaped) of kind, name, data (and a Secret's type); the first 10 hex
# digits with 0, 1, 3, a and e replaced so that the suffix holds no vowel and no look-alike
# digits. The name it encodes is empty: kustomize looks it up as the one key "metadata/name",
# which no object has (so the suffix depends on the content alone).

def _go_json(value):
    text = json.dumps(value, sort_keys=True, separators=(",", ":"), ensure_ascii=False)
    for c, esc in (("<", "\\u003c"), (">", "\\u003e"), ("&", "\\u0026"),
                   ("\u2028", "\\u2028"), ("\u2029", "\\u2029")):
        text = text.replace(c, esc)
    return text


def _hash_suffix(encoded):
    digest = hashlib.sha256(encoded.encode("utf-8")).hexdigest()[:10]
    return digest.translate(str.maketrans({"0": "g", "1": "h", "3": "k", "a": "m", "e": "t"}))


def _generator_data(gen, directory, binary_ok):
    data = {}
    for literal in gen.get("literals", []) or []:
        key, sep, value = str(literal).partition("=")
        if not sep:
            raise KustomizeError(f"literal '{literal}' is not KEY=VALUE")
        data[key] = value
    for entry in gen.get("files", []) or []:
        key, sep, rel = str(entry).partition("=")
        if not sep:
            key, rel = os.path.basename(entry), entry
        path = os.path.normpath(os.path.join(directory, rel))
        if not os.path.isfile(path):
            raise KustomizeError(f"{directory}: generator {gen['name']}: no file {rel}")
        with open(path, "rb") as f:
            raw = f.read()
        if key in data:
            raise KustomizeError(f"generator {gen['name']}: key {key} twice")
        data[key] = raw
    out = {}
    for key, value in data.items():
        if isinstance(value, bytes):
            if binary_ok:
                out[key] = value
                continue
            try:
                value = value.decode("utf-8")
            except UnicodeDecodeError as e:
                raise KustomizeError(f"generator {gen['name']}: {key} is not UTF-8") from e
        out[key] = value
    return out


def _config_map(gen, directory):
    data = _generator_data(gen, directory, binary_ok=False)
    if "type" in gen:
        raise KustomizeError(f"configMapGenerator {gen['name']}: `type` is for Secrets")
    encoded = _go_json({"kind": "ConfigMap", "name": "", "data": data})
    name = f"{gen['name']}-{_hash_suffix(encoded)}"
    obj = {"apiVersion": "v1", "kind": "ConfigMap", "metadata": {"name": name}, "data": data}
    return obj, Generated("ConfigMap", gen["name"], name)


def _kustomize_base64(raw):
    """Base64 as kustomize writes a Secret's value: from 70 characters on, in lines of 70,
    each ended by a newline (kyaml's encodeBase64)."""
    text = base64.b64encode(raw).decode("ascii")
    if len(text) < 70:
        return text
    return "".join(text[i:i + 70] + "\n" for i in range(0, len(text), 70))


def _secret(gen, directory):
    data = _generator_data(gen, directory, binary_ok=True)
    b64 = {k: _kustomize_base64(v if isinstance(v, bytes) else v.encode("utf-8"))
           for k, v in data.items()}
    kind_type = gen.get("type", "Opaque")
    encoded = _go_json({"kind": "Secret", "type": kind_type, "name": "", "data": b64})
    name = f"{gen['name']}-{_hash_suffix(encoded)}"
    obj = {"apiVersion": "v1", "kind": "Secret", "metadata": {"name": name}, "type": kind_type,
           "data": b64}
    return obj, Generated("Secret", gen["name"], name)


# --- JSON patch (RFC 6902).

def _pointer(path):
    if path == "":
        return []
    if not path.startswith("/"):
        raise KustomizeError(f"JSON pointer '{path}' does not start with /")
    return [p.replace("~1", "/").replace("~0", "~") for p in path[1:].split("/")]


def _walk(doc, parts, path):
    node = doc
    for p in parts:
        if isinstance(node, dict):
            if p not in node:
                raise KustomizeError(f"path {path}: no '{p}'")
            node = node[p]
        elif isinstance(node, list):
            if not p.isdigit() or int(p) >= len(node):
                raise KustomizeError(f"path {path}: no index '{p}'")
            node = node[int(p)]
        else:
            raise KustomizeError(f"path {path}: '{p}' is inside a scalar")
    return node


def _add(doc, parts, value, path, replace=False):
    if not parts:
        return value
    parent = _walk(doc, parts[:-1], path)
    last = parts[-1]
    if isinstance(parent, dict):
        if replace and last not in parent:
            raise KustomizeError(f"replace {path}: no '{last}'")
        parent[last] = value
    elif isinstance(parent, list):
        if last == "-" and not replace:
            parent.append(value)
        elif last.isdigit() and int(last) <= len(parent) - (1 if replace else 0):
            if replace:
                parent[int(last)] = value
            else:
                parent.insert(int(last), value)
        else:
            raise KustomizeError(f"path {path}: bad index '{last}'")
    else:
        raise KustomizeError(f"path {path}: the parent is a scalar")
    return doc


def _remove(doc, parts, path):
    if not parts:
        raise KustomizeError("remove of the whole document")
    parent = _walk(doc, parts[:-1], path)
    last = parts[-1]
    if isinstance(parent, dict) and last in parent:
        return parent.pop(last)
    if isinstance(parent, list) and last.isdigit() and int(last) < len(parent):
        return parent.pop(int(last))
    raise KustomizeError(f"remove {path}: nothing there")


def apply_json_patch(doc, ops):
    doc = copy.deepcopy(doc)
    for op in ops:
        if not isinstance(op, dict) or "op" not in op or "path" not in op:
            raise KustomizeError(f"JSON patch operation without op and path: {op}")
        kind, path = op["op"], op["path"]
        parts = _pointer(path)
        if kind in ("add", "replace"):
            if "value" not in op:
                raise KustomizeError(f"{kind} {path}: no value")
            doc = _add(doc, parts, copy.deepcopy(op["value"]), path, replace=kind == "replace")
        elif kind == "remove":
            _remove(doc, parts, path)
        elif kind in ("move", "copy"):
            source = _pointer(op["from"])
            value = (_remove(doc, source, op["from"]) if kind == "move"
                     else copy.deepcopy(_walk(doc, source, op["from"])))
            doc = _add(doc, parts, value, path)
        elif kind == "test":
            if _walk(doc, parts, path) != op.get("value"):
                raise KustomizeError(f"test {path}: the value differs")
        else:
            raise KustomizeError(f"JSON patch: unknown op '{kind}'")
    return doc


def _matches(target, obj):
    api = obj["apiVersion"]
    group, _, version = api.rpartition("/")
    meta = obj["metadata"]
    fields = {"group": group, "version": version, "kind": obj["kind"], "name": meta["name"],
              "namespace": meta.get("namespace", "")}
    for key, pattern in target.items():
        if key == "labelSelector":
            labels = meta.get("labels", {}) or {}
            for term in str(pattern).split(","):
                k, sep, v = term.strip().partition("=")
                if not sep or labels.get(k.strip()) != v.strip():
                    return False
        elif not re.fullmatch(str(pattern), fields[key]):
            return False
    return True


# --- name references from pod templates to generated ConfigMaps and Secrets.

def _pod_spec(obj):
    if obj["kind"] == "Pod":
        return obj.get("spec")
    if obj["kind"] == "CronJob":
        return (obj.get("spec", {}).get("jobTemplate", {}).get("spec", {})
                .get("template", {}).get("spec"))
    if obj["kind"] in POD_TEMPLATE_KINDS:
        return obj.get("spec", {}).get("template", {}).get("spec")
    return None


def _references(spec):
    """(kind, holder dict, key) of every ConfigMap or Secret name a pod spec names."""
    refs = []
    for vol in spec.get("volumes", []) or []:
        if "configMap" in vol:
            refs.append(("ConfigMap", vol["configMap"], "name"))
        if "secret" in vol:
            refs.append(("Secret", vol["secret"], "secretName"))
        for src in (vol.get("projected", {}) or {}).get("sources", []) or []:
            if "configMap" in src:
                refs.append(("ConfigMap", src["configMap"], "name"))
            if "secret" in src:
                refs.append(("Secret", src["secret"], "name"))
    for c in (spec.get("containers", []) or []) + (spec.get("initContainers", []) or []):
        for env in c.get("env", []) or []:
            source = env.get("valueFrom", {}) or {}
            if "configMapKeyRef" in source:
                refs.append(("ConfigMap", source["configMapKeyRef"], "name"))
            if "secretKeyRef" in source:
                refs.append(("Secret", source["secretKeyRef"], "name"))
        for env in c.get("envFrom", []) or []:
            if "configMapRef" in env:
                refs.append(("ConfigMap", env["configMapRef"], "name"))
            if "secretRef" in env:
                refs.append(("Secret", env["secretRef"], "name"))
    for s in spec.get("imagePullSecrets", []) or []:
        refs.append(("Secret", s, "name"))
    return refs


def _fix_references(objects, generated):
    for obj in objects:
        spec = _pod_spec(obj)
        if not spec:
            continue
        ns = obj["metadata"].get("namespace", "")
        for kind, holder, key in _references(spec):
            for g in generated:
                if (g.kind == kind and holder.get(key) == g.original
                        and g.obj["metadata"].get("namespace", "") == ns):
                    holder[key] = g.name


def _sort_key(obj):
    kind = obj["kind"]
    if kind in ORDER_FIRST:
        rank = ORDER_FIRST.index(kind) - len(ORDER_FIRST)
    elif kind in ORDER_LAST:
        rank = 1 + ORDER_LAST.index(kind)
    else:
        rank = 0
    gvk = f"{obj['apiVersion']}, Kind={kind}"
    return (rank, gvk, obj["metadata"].get("namespace", ""), obj["metadata"]["name"])


def _render(directory, seen):
    directory = os.path.abspath(directory)
    if directory in seen:
        raise KustomizeError(f"{directory}: a cycle of kustomizations")
    path = _find_kustomization(directory)
    with open(path, encoding="utf-8") as f:
        k = yaml.safe_load(f) or {}
    unknown = set(k) - SUPPORTED_FIELDS
    if unknown:
        raise KustomizeError(f"{path}: fields this renderer does not support: {sorted(unknown)}")
    if k.get("kind", "Kustomization") != "Kustomization":
        raise KustomizeError(f"{path}: kind {k.get('kind')} (components are not supported)")

    objects, generated = [], []
    for res in k.get("resources", []) or []:
        target = os.path.normpath(os.path.join(directory, res))
        if os.path.isdir(target):
            sub_objects, sub_generated = _render(target, seen | {directory})
            objects += sub_objects
            generated += sub_generated
        elif os.path.isfile(target):
            objects += _load_yaml_documents(target)
        else:
            raise KustomizeError(f"{path}: resource {res} does not exist")

    for field, make in (("configMapGenerator", _config_map), ("secretGenerator", _secret)):
        for gen in k.get(field, []) or []:
            unknown = set(gen) - GENERATOR_FIELDS
            if unknown or "name" not in gen:
                raise KustomizeError(f"{path}: {field} entry {gen}: unsupported or no name")
            obj, g = make(gen, directory)
            g.obj = obj
            objects.append(obj)
            generated.append(g)

    for patch in k.get("patches", []) or []:
        unknown = set(patch) - PATCH_FIELDS
        if unknown:
            raise KustomizeError(f"{path}: patch fields not supported: {sorted(unknown)}")
        if ("path" in patch) == ("patch" in patch):
            raise KustomizeError(f"{path}: a patch needs exactly one of path and patch")
        if "path" in patch:
            with open(os.path.join(directory, patch["path"]), encoding="utf-8") as f:
                ops = yaml.safe_load(f)
        else:
            ops = yaml.safe_load(patch["patch"])
        target = patch.get("target")
        if not isinstance(ops, list):
            raise KustomizeError(f"{path}: only JSON patches (a list of operations) are "
                                 "supported, not strategic-merge patches")
        if not isinstance(target, dict) or set(target) - TARGET_FIELDS:
            raise KustomizeError(f"{path}: a JSON patch needs a target of {sorted(TARGET_FIELDS)}")
        hits = 0
        for i, obj in enumerate(objects):
            if _matches(target, obj):
                try:
                    objects[i] = apply_json_patch(obj, ops)
                except KustomizeError as e:
                    raise KustomizeError(
                        f"{path}: patch {patch.get('path', '(inline)')} on {obj['kind']} "
                        f"{obj['metadata']['name']}: {e}") from e
                hits += 1
        if hits == 0:
            raise KustomizeError(f"{path}: patch target {target} selects nothing")

    if "namespace" in k:
        for obj in objects:
            if obj["kind"] not in CLUSTER_SCOPED:
                obj["metadata"]["namespace"] = k["namespace"]

    _fix_references(objects, generated)

    ids = set()
    for obj in objects:
        key = (obj["apiVersion"], obj["kind"], obj["metadata"].get("namespace", ""),
               obj["metadata"]["name"])
        if key in ids:
            raise KustomizeError(f"{path}: {key} twice")
        ids.add(key)
    return objects, generated


def render(directory):
    """The objects of the kustomization in `directory`, in kustomize's output order."""
    objects, _ = _render(directory, frozenset())
    return sorted(objects, key=_sort_key)


def main(argv):
    if len(argv) != 2:
        print(__doc__.strip().splitlines()[-1], file=sys.stderr)
        return 2
    try:
        objects = render(argv[1])
    except KustomizeError as e:
        print(f"kustomize_lite: {e}", file=sys.stderr)
        return 1
    sys.stdout.write(yaml.safe_dump_all(objects, sort_keys=True, default_flow_style=False))
    return 0


if __name__ == "__main__":
    sys.exit(main(sys.argv))
