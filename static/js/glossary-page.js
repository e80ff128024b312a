// The glossary page: every entry of glossary.js, one table per group.
import { GLOSSARY } from "./glossary.js";
import { $, h, startPage } from "./ui.js";

const UNITS = { degC: "°C", degR: "°R", pps: "lb/s", "1": "dimensionless" };

async function main() {
  await startPage("glossary");
  const groups = [...new Set(GLOSSARY.map((e) => e.group))];
  $("#glossary").replaceChildren(...groups.map((group, i) => h("section", { class: "card", "aria-labelledby": `group-${i}` },
    h("h2", { id: `group-${i}` }, group),
    h("table", { class: "data glossary" },
      h("thead", {}, h("tr", {}, ["Name", "API name", "Unit", "Meaning"].map((c) => h("th", { scope: "col" }, c)))),
      h("tbody", {}, GLOSSARY.filter((e) => e.group === group).map((e) => h("tr", { id: `term-${e.code.replace(/\W+/g, "_")}` },
        h("th", { scope: "row" }, e.name), h("td", {}, h("code", {}, e.code)), h("td", {}, UNITS[e.unit] || e.unit || "–"),
        h("td", {}, e.meaning))))))));
  document.body.dataset.ready = "true";
}

main();
