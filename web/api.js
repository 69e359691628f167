// Interactive API reference: renders /openapi.json (every route, its
// parameters, request body schema and responses) and sends requests with
// the token. Served by the daemon itself; no CDN.
"use strict";

const tokenInput = document.getElementById("token");
tokenInput.value = localStorage.getItem("polnlos-token") || "";
tokenInput.addEventListener("change", () => localStorage.setItem("polnlos-token", tokenInput.value.trim()));

function el(tag, attrs, ...children) {
  const e = document.createElement(tag);
  Object.entries(attrs || {}).forEach(([k, v]) => e.setAttribute(k, v));
  children.forEach((c) => e.append(c));
  return e;
}

// A JSON example of a schema, following $refs (depth-limited).
function example(schema, doc, depth) {
  if (!schema || depth > 6) return null;
  if (schema.$ref) return example(doc.components.schemas[schema.$ref.split("/").pop()], doc, depth + 1);
  if (schema.example !== undefined) return schema.example;
  if (schema.oneOf) return example(schema.oneOf[0], doc, depth + 1);
  if (schema.allOf) return Object.assign({}, ...schema.allOf.map((s) => example(s, doc, depth + 1)));
  if (schema.enum) return schema.enum[0];
  const type = Array.isArray(schema.type) ? schema.type.find((t) => t !== "null") : schema.type;
  if (type === "object" || schema.properties) {
    const out = {};
    const required = new Set(schema.required || []);
    Object.entries(schema.properties || {}).forEach(([k, v]) => {
      if (required.has(k)) out[k] = example(v, doc, depth + 1);
    });
    return out;
  }
  if (type === "array") return [];
  if (type === "string") return "";
  if (type === "integer" || type === "number") return 0;
  if (type === "boolean") return false;
  return null;
}

function operation(doc, path, method, op) {
  const params = (op.parameters || []).filter((p) => p.in === "path");
  const inputs = params.map((p) => el("label", {}, `${p.name} `, el("input", { name: p.name, size: "12" })));
  const query = el("input", { name: "query", size: "30", placeholder: "query string, e.g. limit=10" });
  const bodySchema = op.requestBody && op.requestBody.content["application/json"] && op.requestBody.content["application/json"].schema;
  const body = bodySchema ? el("textarea", { rows: "6", cols: "70" }) : null;
  if (body) body.value = JSON.stringify(example(bodySchema, doc, 0), null, 1);
  const out = el("pre", { class: "response" });
  const send = el("button", { type: "button" }, "Send");
  send.addEventListener("click", async () => {
    let url = path;
    params.forEach((p, k) => { url = url.replace(`{${p.name}}`, encodeURIComponent(inputs[k].querySelector("input").value)); });
    if (query.value) url += "?" + query.value;
    const headers = {};
    const t = tokenInput.value.trim();
    if (t) headers["Authorization"] = "Bearer " + t;
    if (body) headers["Content-Type"] = "application/json";
    const r = await fetch(url, { method: method.toUpperCase(), headers, body: body ? body.value : undefined });
    const type = r.headers.get("content-type") || "";
    const text = type.includes("json") || type.startsWith("text/plain") ? await r.text() : `(${type}, ${(await r.blob()).size} bytes)`;
    out.textContent = `${r.status} ${r.statusText}\n${text}`;
  });
  const responses = Object.entries(op.responses || {}).map(([code, r]) => el("li", {}, `${code}: ${r.description || ""}`));
  return el("section", { class: "operation", id: `${method}-${path}` },
    el("h3", {}, `${method.toUpperCase()} ${path}`),
    el("p", {}, (op.description || op.summary || "").trim()),
    el("ul", {}, ...responses),
    el("div", {}, ...inputs, method === "get" ? query : ""),
    body || "",
    el("div", {}, send),
    out);
}

(async () => {
  const doc = await (await fetch("/openapi.json")).json();
  const main = document.getElementById("routes");
  Object.entries(doc.paths).forEach(([path, item]) => {
    ["get", "post", "put", "delete"].forEach((m) => { if (item[m]) main.append(operation(doc, path, m, item[m])); });
  });
})();
