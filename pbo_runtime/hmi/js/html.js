// One import for the page's components: `html` templates (htm on Preact's h), rendering and hooks.
import { h, render, Fragment } from "preact";
import { useState, useEffect, useRef, useMemo, useCallback, useReducer, useContext } from "preact/hooks";
import htm from "htm";

export const html = htm.bind(h);
export { h, render, Fragment, useState, useEffect, useRef, useMemo, useCallback, useReducer, useContext };
