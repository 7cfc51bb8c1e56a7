%% @doc Public API of the reference Virtual Agents: Erlang VAs that join
%% EVATAR through agent_bridge_client as any multi-agent system would, with
%% sensor and actuator emulators built from their BIL body and an
%% Observe-Choose-Act cycle around a pure mind (docs/scenarios.md), and the
%% rules file of the smart-home VAs (docs/rules.md). The agents only: the
%% scenarios that make listeners, pairings and simulated worlds for them are
%% the demo's (evatar_demo), as a MAS of one's own brings its own set-up.
-module(reference_agents).

-export([start_va/1, stop_va/1, inspect/1, traffic/1, tell/3, introduce/2]).
-export([parse_rules/1, rules_error/2]).
-export([minute_of_day/1, lexicon_text/1, lexicons_agreed/1]).

-export_type([va_opts/0]).

-type va_opts() :: reference_agents_va:opts().

%% @doc Starts a VA linked to the caller (see reference_agents_va:opts()):
%% its name, its mind (a `reference_agents_mind' module and its arguments),
%% its body (a bil:description(), or `none' for a VA without an Avatar),
%% and for an embodied VA the bridge endpoints, the pairing and the
%% credential. The caller receives `{reference_agents, Name, Term}' for
%% each `{notify, Term}' the mind chooses.
-spec start_va(va_opts()) -> {ok, pid()}.
start_va(Opts) -> reference_agents_va:start_link(Opts).

%% @doc Says Bye to EVATAR and stops the VA.
-spec stop_va(pid()) -> ok.
stop_va(Va) -> reference_agents_va:stop(Va).

%% @doc The VA's state (connecting, observing, testing, embodied or
%% unembodied), its last embodiment report, what its mind shows, and the
%% states it went through.
-spec inspect(pid()) -> map().
inspect(Va) -> reference_agents_va:inspect(Va).

%% @doc What a VA has handled and sent (reference_agents_va:traffic/1):
%% a few integers, for a clock that runs in lockstep with it.
-spec traffic(pid()) -> reference_agents_va:traffic().
traffic(Va) -> reference_agents_va:traffic(Va).

%% @doc A MAS message to a VA, from the VA named `From'.
-spec tell(pid(), binary(), term()) -> ok.
tell(Va, From, Message) -> reference_agents_va:tell(Va, From, Message).

%% @doc Tells a VA the pids of the other VAs it talks to, by name.
-spec introduce(pid(), #{binary() => pid()}) -> ok.
introduce(Va, Peers) -> reference_agents_va:introduce(Va, Peers).

%% @doc Reads a rules file (docs/rules.md).
-spec parse_rules(file:filename_all()) ->
          {ok, reference_agents_rules:rules()}
        | {error, reference_agents_rules:error() | {file, term()}}.
parse_rules(File) -> reference_agents_rules:parse_file(File).

%% @doc `File:Line: what is wrong', for a person.
-spec rules_error(file:filename_all(), reference_agents_rules:error() | {file, term()}) -> binary().
rules_error(File, Error) -> reference_agents_rules:format_error(File, Error).

%% @doc The minute of the day `HH:MM' names (`HH:MM:SS' too), as the rules
%% file reads times; `undefined' for anything else.
-spec minute_of_day(binary()) -> 0..1439 | undefined.
minute_of_day(HHMM) -> reference_agents_policy:minute(HHMM).

%% @doc A lexicon (a coordinator's or robot VA's `lexicon', from
%% {@link inspect/1}) as one line for people.
-spec lexicon_text(reference_agents_lexicon:lexicon()) -> iodata().
lexicon_text(Lexicon) -> reference_agents_lexicon:encode(Lexicon).

%% @doc True when every lexicon given is the same one (and there is one).
-spec lexicons_agreed([reference_agents_lexicon:lexicon()]) -> boolean().
lexicons_agreed(Lexicons) -> reference_agents_lexicon:agreed(Lexicons).
