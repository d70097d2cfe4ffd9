// Vite imports a file as text with "?raw" (the update codec fixture, update_codec.test.ts).
declare module "*?raw" {
  const text: string;
  export default text;
}
