// Form fields from a pydantic JSON schema (an operator's config), with the same checks the server
// makes: types, bounds, two-number ranges (low ≤ high), nullable fields. Values equal to the
// default are left out of the config, so the server's defaults apply.
import { h } from "./dom.js";

function resolve(schema, root) {
  if (schema?.$ref) {
    const name = schema.$ref.split("/").pop();
    return resolve({ ...(root.$defs?.[name] ?? root.definitions?.[name] ?? {}), ...schema, $ref: undefined }, root);
  }
  if (schema?.allOf?.length === 1) return resolve({ ...schema.allOf[0], ...schema, allOf: undefined }, root);
  return schema ?? {};
}

// {nullable, schema}: the non-null branch of anyOf/oneOf.
function unwrap(schema, root) {
  const s = resolve(schema, root);
  const options = s.anyOf ?? s.oneOf;
  if (!options) return { nullable: s.type === "null", schema: s };
  const nonNull = options.filter((o) => o.type !== "null");
  const nullable = nonNull.length < options.length;
  const chosen = resolve(nonNull[0] ?? {}, root);
  return { nullable, schema: { ...chosen, default: s.default, description: s.description ?? chosen.description, title: s.title ?? chosen.title } };
}

function numberInput(schema, value, label) {
  const attrs = { type: "number", step: schema.type === "integer" ? 1 : "any", "aria-label": label };
  if (schema.minimum !== undefined) attrs.min = schema.minimum;
  if (schema.maximum !== undefined) attrs.max = schema.maximum;
  const input = h("input", attrs);
  if (value !== null && value !== undefined) input.value = String(value);
  return input;
}

function checkNumber(text, schema, nullable, what) {
  if (text.trim() === "") {
    if (nullable) return { value: null };
    return { error: `${what}: a number is required` };
  }
  const value = Number(text);
  if (!Number.isFinite(value)) return { error: `${what}: "${text}" is not a number` };
  if (schema.type === "integer" && !Number.isInteger(value)) return { error: `${what}: must be a whole number` };
  if (schema.minimum !== undefined && value < schema.minimum) return { error: `${what}: must be ≥ ${schema.minimum}` };
  if (schema.maximum !== undefined && value > schema.maximum) return { error: `${what}: must be ≤ ${schema.maximum}` };
  if (schema.exclusiveMinimum !== undefined && value <= schema.exclusiveMinimum) {
    return { error: `${what}: must be > ${schema.exclusiveMinimum}` };
  }
  if (schema.exclusiveMaximum !== undefined && value >= schema.exclusiveMaximum) {
    return { error: `${what}: must be < ${schema.exclusiveMaximum}` };
  }
  return { value };
}

// One field: {name, element, read() -> {value} | {error}, isDefault(value)}.
export function schemaField(name, propSchema, root) {
  const { nullable, schema } = unwrap(propSchema, root);
  const def = schema.default;
  const title = name;
  const description = schema.description ?? "";
  let control;
  let read;
  const pair = schema.type === "array" && (schema.prefixItems?.length === 2 || (schema.minItems === 2 && schema.maxItems === 2));
  if (schema.enum) {
    control = h("select", {}, (nullable ? [null, ...schema.enum] : schema.enum).map((v) => h("option", { value: JSON.stringify(v) }, v === null ? "none" : String(v))));
    control.value = JSON.stringify(def ?? null);
    read = () => ({ value: JSON.parse(control.value) });
  } else if (schema.type === "boolean") {
    control = h("input", { type: "checkbox", checked: Boolean(def) });
    read = () => ({ value: control.checked });
  } else if (schema.type === "number" || schema.type === "integer") {
    control = numberInput(schema, def, title);
    read = () => checkNumber(control.value, schema, nullable, title);
  } else if (pair) {
    const items = schema.prefixItems ?? [schema.items ?? {}, schema.items ?? {}];
    const lo = numberInput(resolve(items[0], root), def?.[0], `${title} low`);
    const hi = numberInput(resolve(items[1], root), def?.[1], `${title} high`);
    control = h("span", { class: "range" }, lo, " – ", hi);
    read = () => {
      if (lo.value.trim() === "" && hi.value.trim() === "" && nullable) return { value: null };
      const a = checkNumber(lo.value, resolve(items[0], root), false, `${title} low`);
      if (a.error) return a;
      const b = checkNumber(hi.value, resolve(items[1], root), false, `${title} high`);
      if (b.error) return b;
      if (name.endsWith("_range") && a.value > b.value) return { error: `${title}: low ${a.value} is above high ${b.value}` };
      return { value: [a.value, b.value] };
    };
  } else if (schema.type === "string") {
    control = h("input", { type: "text", value: def ?? "" });
    read = () => ({ value: control.value === "" && nullable ? null : control.value });
  } else {
    // anything else (lists, objects): JSON text
    control = h("input", { type: "text", class: "json", value: def === undefined ? "" : JSON.stringify(def) });
    read = () => {
      if (control.value.trim() === "") return nullable ? { value: null } : { error: `${title}: a value is required` };
      try {
        return { value: JSON.parse(control.value) };
      } catch {
        return { error: `${title}: not valid JSON` };
      }
    };
  }
  const element = h(
    "label",
    { class: "schema-field", dataset: { param: name }, title: description },
    h("span", { class: "field-name" }, title, nullable ? h("span", { class: "muted" }, " (optional)") : null),
    control,
    description ? h("span", { class: "field-help" }, description) : null,
  );
  return { name, element, read, isDefault: (value) => JSON.stringify(value) === JSON.stringify(def ?? null) };
}

export function schemaFields(schema) {
  const root = schema ?? {};
  const resolved = resolve(root, root);
  return Object.entries(resolved.properties ?? {}).map(([name, prop]) => schemaField(name, prop, root));
}
