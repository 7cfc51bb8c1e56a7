%% @doc Internal. The script of the people in the simulated house
%% (docs/avatars.md section 4.3): checking a script given as Erlang terms,
%% parsing the text form line by line (no atoms are made from the file), and
%% working out when each step is due.
-module(avatar_sim_script).

-export([check/1, parse/1, due/4]).

-export_type([step/0, action/0, checked/0]).

-type when_() :: {at, string() | binary()} | {delay, non_neg_integer()}
               | {offset, non_neg_integer()}.
-type action() :: {go, binary()} | still | moving | {say, binary()} | {keypad, binary()}.
-type step() :: {when_(), binary(), action()}.
%% Steps with their time resolved to a form `due/4' reads.
-type checked() :: {{at, non_neg_integer()} | {delay, non_neg_integer()}
                    | {offset, non_neg_integer()}, binary(), action()}.

%% @doc Checks a script given as terms; `N' in an error is the step's
%% position, from 1.
-spec check([step()]) -> {ok, [checked()]} | {error, {script, pos_integer(), binary()}}.
check(Steps) when is_list(Steps) ->
    check(Steps, 1, []);
check(_) ->
    {error, {script, 1, <<"a script is a list of {When, Who, Action} steps">>}}.

check([], _N, Acc) ->
    {ok, lists:reverse(Acc)};
check([{When, Who, Action} | Rest], N, Acc) when is_binary(Who), Who =/= <<>> ->
    case {check_when(When), check_action(Action)} of
        {{ok, W}, ok} -> check(Rest, N + 1, [{W, Who, Action} | Acc]);
        {{error, Why}, _} -> {error, {script, N, Why}};
        {_, {error, Why}} -> {error, {script, N, Why}}
    end;
check([_ | _], N, _Acc) ->
    {error, {script, N, <<"a step is {When, Who, Action} with Who a non-empty binary">>}}.

check_when({at, Time}) when is_list(Time); is_binary(Time) ->
    case clock_time(iolist_to_binary(Time)) of
        {ok, S} -> {ok, {at, S}};
        error -> {error, <<"time of day must be HH:MM or HH:MM:SS">>}
    end;
check_when({delay, Ms}) when is_integer(Ms), Ms >= 0 -> {ok, {delay, Ms}};
check_when({offset, Ms}) when is_integer(Ms), Ms >= 0 -> {ok, {offset, Ms}};
check_when(_) -> {error, <<"When must be {at, \"HH:MM\"}, {delay, Ms} or {offset, Ms}">>}.

check_action({go, Room}) when is_binary(Room), Room =/= <<>> -> ok;
check_action(still) -> ok;
check_action(moving) -> ok;
check_action({say, Text}) when is_binary(Text) -> ok;
check_action({keypad, Code}) when is_binary(Code) -> ok;
check_action(_) ->
    {error, <<"Action must be {go, Room}, still, moving, {say, Text} or {keypad, Code}">>}.

%% @doc Parses the text form: one step per line, `#' starts a comment.
-spec parse(binary()) -> {ok, [checked()]} | {error, {script, pos_integer(), binary()}}.
parse(Text) ->
    Lines = binary:split(Text, [<<"\r\n">>, <<"\n">>], [global]),
    parse_lines(lists:zip(lists:seq(1, length(Lines)), Lines), []).

parse_lines([], Acc) ->
    {ok, lists:reverse(Acc)};
parse_lines([{N, Line0} | Rest], Acc) ->
    Line = string:trim(hd(binary:split(Line0, <<"#">>))),
    case Line of
        <<>> -> parse_lines(Rest, Acc);
        _ ->
            case parse_line(Line) of
                {ok, Step} -> parse_lines(Rest, [Step | Acc]);
                {error, Why} -> {error, {script, N, Why}}
            end
    end.

parse_line(Line) ->
    case string:lexemes(Line, " \t") of
        [When, Who, Verb | Args] ->
            case parse_when(When) of
                {ok, W} ->
                    case parse_action(Verb, Args, Line) of
                        {ok, A} -> {ok, {W, Who, A}};
                        {error, _} = E -> E
                    end;
                {error, _} = E -> E
            end;
        _ ->
            {error, <<"expected: when who action [argument]">>}
    end.

parse_when(<<"+", D/binary>>) -> duration(D, delay);
parse_when(<<"@", D/binary>>) -> duration(D, offset);
parse_when(T) ->
    case clock_time(T) of
        {ok, S} -> {ok, {at, S}};
        error -> {error, <<"bad time '", T/binary, "': use HH:MM[:SS], +N<unit> or @N<unit>">>}
    end.

duration(D, Kind) ->
    case string:to_integer(binary_to_list(D)) of
        {N, Unit} when is_integer(N), N >= 0 ->
            case unit(Unit) of
                {ok, K} -> {ok, {Kind, N * K}};
                error -> {error, <<"bad unit in '", D/binary, "': use ms, s, m or h">>}
            end;
        _ ->
            {error, <<"bad duration '", D/binary, "'">>}
    end.

unit("ms") -> {ok, 1};
unit("s") -> {ok, 1000};
unit("m") -> {ok, 60000};
unit("h") -> {ok, 3600000};
unit(_) -> error.

parse_action(<<"go">>, [Room], _Line) -> {ok, {go, Room}};
parse_action(<<"still">>, [], _Line) -> {ok, still};
parse_action(<<"moving">>, [], _Line) -> {ok, moving};
parse_action(<<"keypad">>, [Code], _Line) -> {ok, {keypad, Code}};
parse_action(<<"say">>, [_ | _] = Words, _Line) ->
    {ok, {say, iolist_to_binary(lists:join(<<" ">>, Words))}};
parse_action(Verb, Args, _Line) when Verb =:= <<"go">>; Verb =:= <<"still">>;
                                      Verb =:= <<"moving">>; Verb =:= <<"keypad">>;
                                      Verb =:= <<"say">> ->
    {error, <<"wrong number of arguments for ", Verb/binary, " (",
              (integer_to_binary(length(Args)))/binary, ")">>};
parse_action(Verb, _Args, _Line) ->
    {error, <<"unknown action '", Verb/binary, "': use go, still, moving, say or keypad">>}.

clock_time(T) ->
    case [string:to_integer(P) || P <- string:split(binary_to_list(T), ":", all)] of
        [{H, []}, {M, []}] when is_integer(H), H >= 0, H < 24, is_integer(M), M >= 0, M < 60 ->
            {ok, H * 3600 + M * 60};
        [{H, []}, {M, []}, {S, []}] when is_integer(H), H >= 0, H < 24, is_integer(M), M >= 0,
                                          M < 60, is_integer(S), S >= 0, S < 60 ->
            {ok, H * 3600 + M * 60 + S};
        _ -> error
    end.

%% @doc When a step is due (ms since 1970), given the previous step's time,
%% the clock's start and the offset of local time from UTC in minutes.
-spec due(checked(), integer(), integer(), integer()) -> integer().
due({{delay, Ms}, _, _}, Previous, _Start, _Offset) -> Previous + Ms;
due({{offset, Ms}, _, _}, _Previous, Start, _Offset) -> Start + Ms;
due({{at, Seconds}, _, _}, Previous, _Start, Offset) ->
    LocalPrev = Previous + Offset * 60000,
    Midnight = LocalPrev - floor_mod(LocalPrev, 86400000),
    Candidate = Midnight + Seconds * 1000 - Offset * 60000,
    case Candidate < Previous of
        true -> Candidate + 86400000;
        false -> Candidate
    end.

floor_mod(A, B) ->
    R = A rem B,
    case R < 0 of true -> R + B; false -> R end.
