import { defineConfig } from "vite";

// Relative base so the built viewer works under any path (e.g. behind a proxy prefix).
export default defineConfig({
  base: "./",
  build: {
    outDir: "dist",
    emptyOutDir: true,
    chunkSizeWarningLimit: 1024,
  },
  test: {
    include: ["test/**/*.test.ts"],
    environment: "node",
    // Conditions, not speed: the default 5 s timed out on a busy 2-core machine.
    testTimeout: 60_000,
  },
} as any);
