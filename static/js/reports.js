// "Export PDF" and "Export Excel": the report of this engine or of the fleet, made by the API
// (GET .../report?format=pdf|xlsx) and saved in the browser's downloads.
import { apiDownload } from "./api.js";
import { h, showError } from "./ui.js";

const FORMATS = [["pdf", "Export PDF", "application/pdf"],
  ["xlsx", "Export Excel", "application/vnd.openxmlformats-officedocument.spreadsheetml.sheet"]];

// The two buttons for the report at ``path``; a failure is shown in ``message``.
export function reportButtons(path, message, filename) {
  return FORMATS.map(([format, label, accept]) => {
    const button = h("button", { type: "button", class: "secondary", id: `export-${format}` }, label);
    button.addEventListener("click", async () => {
      button.disabled = true;
      button.textContent = "Preparing…";
      button.setAttribute("aria-busy", "true");
      try {
        await apiDownload(path, { query: { format }, accept, filename: `${filename}.${format}` });
      } catch (err) {
        showError(message, err, `${label} report`);
      } finally {
        button.disabled = false;
        button.textContent = label;
        button.removeAttribute("aria-busy");
      }
    });
    return button;
  });
}
