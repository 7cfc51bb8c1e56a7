%% @doc Internal. A small, safe evaluator of the Jinja forms Home Assistant
%% users write in MQTT discovery configs (`value_template',
%% `command_template', `brightness_template'...): `{{ expr }}', `{% if %}',
%% `{% elif %}', `{% else %}', `{% endif %}', `{# comments #}' and the `-'
%% whitespace control. Expressions: `value', `value_json.a.b[0]',
%% `value_json['key']', numbers, strings, `true'/`false'/`none', `+ - * / //
%% %', `~' (concatenation), comparisons (`== != < <= > >= in', `not in'),
%% `and or not', `x if c else y', filters (`float int round default d lower
%% upper string abs trim length multiply replace iif is_defined'), the
%% functions `float(x)', `int(x)', `iif(c, t, f)', and the tests
%% `is [not] defined | none | number | string'. Anything else is an
%% `{error, Message}' naming the construct; input never raises and never
%% makes an atom. docs/mqtt.md section 2.3 lists it with the limits.
%%
%% API (for every family that reads HA templates):
%% <ul>
%% <li>`parse(Text) -> {ok, T} | {error, Msg}' (and `parse/2' with
%%     `max_size', `max_depth'): check once, when the config arrives.</li>
%% <li>`render(T, Vars) -> {ok, Binary} | {error, Msg}' (and `render/3' with
%%     `max_steps', `max_output'): the text, as HA renders it.</li>
%% <li>`value(T, Vars) -> {ok, Value} | {error, Msg}': a template that is one
%%     `{{ expr }}' gives the expression's value itself (a number stays a
%%     number); any other template gives its text.</li>
%% <li>`payload_vars(Payload)': the variables of a state template:
%%     `value' (the payload as text) and `value_json' (its JSON, when it is
%%     JSON). Command templates take `#{<<"value">> => V}' or the names HA
%%     gives (`brightness', `red'...).</li>
%% <li>`reads(T, Name)': the template reads variable `Name'.</li>
%% <li>`path(T) -> {ok, raw | {json, Path}} | error': the template is a plain
%%     `{{ value }}' or `{{ value_json.path }}' (filters `float', `int',
%%     `string', `round' allowed), which the spec can read without it.</li>
%% </ul>
%% Variables are `#{binary() => value()}' with JSON values
%% (evatar_json) plus `undefined'.
-module(mqtt_avatar_template).

%% OTP 25's type optimisation pass (beam_ssa_type) takes about 15 s of CPU on
%% this module's parser and evaluator, 95 % of its compile time; without it
%% the module compiles in about 1 s. `make test' compiles each module five
%% or six times (two profiles, and cover for EUnit, Common Test and the
%% report). The pass only optimises: what the code does is the same.
-compile([no_type_opt]).

-export([parse/1, parse/2, render/2, render/3, value/2, value/3, payload_vars/1, path/1,
         reads/2, to_text/1, limits/0]).

-export_type([template/0, value/0, vars/0]).

-type value() :: evatar_json:json() | undefined.
-type vars() :: #{binary() => value()}.
-opaque template() :: {tpl, [node_()]}.
-type node_() :: {text, binary()} | {out, expr()} | {'if', [{expr(), [node_()]}], [node_()]}.
-type expr() :: tuple().
-type parse_opts() :: #{max_size => pos_integer(), max_depth => pos_integer()}.
-type render_opts() :: #{max_steps => pos_integer(), max_output => pos_integer()}.

%% Defaults of the limits (docs/mqtt.md section 2.3).
-define(MAX_SIZE, 4096).
-define(MAX_DEPTH, 32).
-define(MAX_STEPS, 10000).
-define(MAX_OUTPUT, 65536).
%% Numbers beyond these are an error, not a bignum.
-define(MAX_INT, (1 bsl 64)).
-define(MAX_FLOAT, 1.0e300).

%% ---------------------------------------------------------------------------
%% API
%% ---------------------------------------------------------------------------

%% @doc The default limits.
-spec limits() -> #{max_size := pos_integer(), max_depth := pos_integer(),
                    max_steps := pos_integer(), max_output := pos_integer()}.
limits() ->
    #{max_size => ?MAX_SIZE, max_depth => ?MAX_DEPTH, max_steps => ?MAX_STEPS,
      max_output => ?MAX_OUTPUT}.

%% @doc Parses a template with the default limits.
-spec parse(binary()) -> {ok, template()} | {error, binary()}.
parse(Text) -> parse(Text, #{}).

%% @doc Parses a template: `max_size' bytes of text, `max_depth' nesting of
%% expressions and `{% if %}' blocks.
-spec parse(binary(), parse_opts()) -> {ok, template()} | {error, binary()}.
parse(Text, Opts) when is_binary(Text) ->
    MaxSize = maps:get(max_size, Opts, ?MAX_SIZE),
    case {byte_size(Text) > MaxSize, unicode:characters_to_binary(Text)} of
        {true, _} ->
            {error, iolist_to_binary(io_lib:format("template longer than ~b bytes", [MaxSize]))};
        {false, Text} ->
            try
                Parts = split(Text, 0, []),
                {Nodes, []} = blocks(Parts, maps:get(max_depth, Opts, ?MAX_DEPTH), top),
                {ok, {tpl, Nodes}}
            catch
                throw:{tpl_error, Message} -> {error, iolist_to_binary(Message)}
            end;
        {false, _} ->
            {error, <<"template is not UTF-8 text">>}
    end;
parse(_, _) ->
    {error, <<"template is not text">>}.

%% @doc Renders with the default limits.
-spec render(template(), vars()) -> {ok, binary()} | {error, binary()}.
render(T, Vars) -> render(T, Vars, #{}).

%% @doc Renders: at most `max_steps' evaluation steps and `max_output' bytes.
-spec render(template(), vars(), render_opts()) -> {ok, binary()} | {error, binary()}.
render({tpl, Nodes}, Vars, Opts) ->
    run(fun() -> iolist_to_binary(render_nodes(Nodes, Vars)) end, Opts).

%% @doc The value of a one-expression template (`{{ x }}' with nothing
%% around it but whitespace); the rendered text of any other.
-spec value(template(), vars()) -> {ok, value()} | {error, binary()}.
value(T, Vars) -> value(T, Vars, #{}).

%% @doc As `value/2' with limits.
-spec value(template(), vars(), render_opts()) -> {ok, value()} | {error, binary()}.
value({tpl, Nodes} = T, Vars, Opts) ->
    case [N || N <- Nodes, not blank(N)] of
        [{out, E}] -> run(fun() -> eval(E, Vars) end, Opts);
        _ -> render(T, Vars, Opts)
    end.

%% @doc The variables of a state template for an MQTT payload: `value', and
%% `value_json' when the payload is JSON.
-spec payload_vars(binary()) -> vars().
payload_vars(Payload) ->
    Json = case evatar_json:decode(Payload) of
               {ok, J} -> J;
               {error, _} -> undefined
           end,
    Text = case unicode:characters_to_binary(Payload) of
               Payload -> Payload;
               _ -> undefined
           end,
    #{<<"value">> => Text, <<"value_json">> => Json}.

%% @doc A plain path: `{{ value }}' or `{{ value_json.a.b }}', with only
%% filters that do not change a value read as text (`float', `int',
%% `string', `round', `trim').
-spec path(template()) -> {ok, raw | {json, [binary()]}} | error.
path({tpl, Nodes}) ->
    case [N || N <- Nodes, not blank(N)] of
        [{out, E}] -> expr_path(E);
        _ -> error
    end.

%% @doc True when the template reads variable `Name' anywhere (`value_json':
%% the template wants the payload as JSON).
-spec reads(template(), binary()) -> boolean().
reads({tpl, Nodes}, Name) ->
    reads_term(Nodes, Name).

reads_term({var, N}, Name) -> N =:= Name;
reads_term(T, Name) when is_tuple(T) -> reads_term(tuple_to_list(T), Name);
reads_term(L, Name) when is_list(L) -> lists:any(fun(X) -> reads_term(X, Name) end, L);
reads_term(_, _Name) -> false.

%% @doc A value as HA writes it in a template's output: numbers in the
%% shortest form, `True'/`False'/`None', the undefined value as nothing,
%% lists and objects as JSON.
-spec to_text(value()) -> binary().
to_text(undefined) -> <<>>;
to_text(null) -> <<"None">>;
to_text(true) -> <<"True">>;
to_text(false) -> <<"False">>;
to_text(B) when is_binary(B) -> B;
to_text(N) when is_number(N) -> evatar_json:to_text(N);
to_text(V) -> evatar_json:encode(V).

%% ---------------------------------------------------------------------------
%% Template text: {{ }}, {% %}, {# #}
%% ---------------------------------------------------------------------------

%% Splits into [{text, Bin} | {expr, Offset, Bin} | {tag, Offset, Bin}],
%% applying the `-' whitespace control.
split(Text, Offset, Acc) ->
    case binary:match(Text, [<<"{{">>, <<"{%">>, <<"{#">>], [{scope, {Offset, byte_size(Text) - Offset}}]) of
        nomatch ->
            lists:reverse(add_text(binary:part(Text, Offset, byte_size(Text) - Offset), Acc));
        {Start, 2} ->
            Open = binary:part(Text, Start, 2),
            Close = case Open of
                        <<"{{">> -> <<"}}">>;
                        <<"{%">> -> <<"%}">>;
                        <<"{#">> -> <<"#}">>
                    end,
            Before = binary:part(Text, Offset, Start - Offset),
            case binary:match(Text, Close, [{scope, {Start + 2, byte_size(Text) - Start - 2}}]) of
                nomatch ->
                    fail(["'", Open, "' at offset ", integer_to_list(Start), " is never closed by '",
                          Close, "'"]);
                {End, 2} ->
                    Inner0 = binary:part(Text, Start + 2, End - Start - 2),
                    {LStrip, Inner1} = case Inner0 of
                                           <<"-", R/binary>> -> {true, R};
                                           <<"+", R/binary>> -> {false, R};
                                           _ -> {false, Inner0}
                                       end,
                    {RStrip, Inner} = case byte_size(Inner1) > 0 andalso binary:last(Inner1) of
                                          $- -> {true, binary:part(Inner1, 0, byte_size(Inner1) - 1)};
                                          $+ -> {false, binary:part(Inner1, 0, byte_size(Inner1) - 1)};
                                          _ -> {false, Inner1}
                                      end,
                    Before1 = case LStrip of
                                  true -> string:trim(Before, trailing);
                                  false -> Before
                              end,
                    Acc1 = add_text(Before1, Acc),
                    Part = case Open of
                               <<"{{">> -> [{expr, Start + 2, Inner}];
                               <<"{%">> -> [{tag, Start + 2, Inner}];
                               <<"{#">> -> []
                           end,
                    Mark = [rstrip || RStrip],
                    split(Text, End + 2, Mark ++ Part ++ Acc1)
            end
    end.

%% A `-' before a closing delimiter strips the whitespace of the text after it.
add_text(<<>>, [rstrip | Acc]) -> Acc;
add_text(T, [rstrip | Acc]) -> add_text(string:trim(T, leading), Acc);
add_text(<<>>, Acc) -> Acc;
add_text(T, Acc) -> [{text, T} | Acc].

%% Builds the node tree from the parts; `top', `if' say where we are.
blocks(Parts, Depth, Where) ->
    blocks(Parts, Depth, Where, []).

blocks([], _Depth, top, Acc) ->
    {lists:reverse(Acc), []};
blocks([], _Depth, 'if', _Acc) ->
    fail("'{% if %}' without '{% endif %}'");
blocks([{text, T} | Rest], Depth, Where, Acc) ->
    blocks(Rest, Depth, Where, [{text, T} | Acc]);
blocks([rstrip | Rest], Depth, Where, Acc) ->
    blocks(Rest, Depth, Where, Acc);
blocks([{expr, Off, Text} | Rest], Depth, Where, Acc) ->
    blocks(Rest, Depth, Where, [{out, expression(Text, Off, Depth)} | Acc]);
blocks([{tag, Off, Text} | Rest] = All, Depth, Where, Acc) ->
    case tag(Text, Off) of
        {'if', Cond} ->
            Depth > 1 orelse fail("'{% if %}' blocks nested too deeply"),
            {Node, Rest1} = if_block(expression(Cond, Off, Depth), Rest, Depth - 1, []),
            blocks(Rest1, Depth, Where, [Node | Acc]);
        End when Where =:= 'if', (End =:= else orelse End =:= endif
                                  orelse element(1, End) =:= elif) ->
            {lists:reverse(Acc), All};
        Other ->
            fail(["'{% ", tag_name(Other), " %}' without '{% if %}' at offset ",
                  integer_to_list(Off)])
    end.

if_block(Cond, Parts, Depth, Branches) ->
    {Body, Rest} = blocks(Parts, Depth, 'if'),
    [{tag, Off, Text} | Rest1] = Rest,
    case tag(Text, Off) of
        {elif, C} -> if_block(expression(C, Off, Depth), Rest1, Depth, [{Cond, Body} | Branches]);
        else ->
            {Else, Rest2} = blocks(Rest1, Depth, 'if'),
            case Rest2 of
                [{tag, Off2, T2} | Rest3] ->
                    case tag(T2, Off2) of
                        endif -> {{'if', lists:reverse([{Cond, Body} | Branches]), Else}, Rest3};
                        Other -> fail(["'{% ", tag_name(Other), " %}' after '{% else %}' at offset ",
                                       integer_to_list(Off2)])
                    end
            end;
        endif -> {{'if', lists:reverse([{Cond, Body} | Branches]), []}, Rest1}
    end.

tag(Text, Off) ->
    Trimmed = string:trim(Text),
    {Word, Rest} = case re:run(Trimmed, <<"^([A-Za-z_]+)(.*)$">>, [{capture, all_but_first, binary},
                                                                   dotall]) of
                       {match, [W, R]} -> {W, R};
                       nomatch -> {Trimmed, <<>>}
                   end,
    case {Word, string:trim(Rest)} of
        {<<"if">>, C} when C =/= <<>> -> {'if', C};
        {<<"elif">>, C} when C =/= <<>> -> {elif, C};
        {<<"else">>, <<>>} -> else;
        {<<"endif">>, <<>>} -> endif;
        _ -> fail(["unsupported construct '{% ", printable(Word), " %}' at offset ",
                   integer_to_list(Off), " (supported: if, elif, else, endif)"])
    end.

tag_name({elif, _}) -> "elif";
tag_name(else) -> "else";
tag_name(endif) -> "endif".

blank({text, T}) -> string:trim(T) =:= <<>>;
blank(_) -> false.

%% ---------------------------------------------------------------------------
%% Expressions: tokens
%% ---------------------------------------------------------------------------

expression(Text, Off, Depth) ->
    Tokens = tokens(Text, Off),
    case parse_expr(Tokens, Depth) of
        {E, [{eof, _}]} -> E;
        {_, [T | _]} -> unexpected(T)
    end.

tokens(Text, Base) -> tokens(Text, 0, Base, []).

tokens(Text, I, Base, Acc) when I >= byte_size(Text) ->
    lists:reverse([{eof, Base + I} | Acc]);
tokens(Text, I, Base, Acc) ->
    Off = Base + I,
    case binary:at(Text, I) of
        C when C =:= $\s; C =:= $\t; C =:= $\n; C =:= $\r ->
            tokens(Text, I + 1, Base, Acc);
        C when C >= $0, C =< $9 ->
            {match, [N]} = re:run(Text, <<"\\G[0-9]+(\\.[0-9]+)?([eE][-+]?[0-9]+)?">>,
                                  [{offset, I}, {capture, first, binary}]),
            tokens(Text, I + byte_size(N), Base, [{num, Off, number(N)} | Acc]);
        C when C =:= $"; C =:= $' ->
            {S, Close} = string_literal(Text, I + 1, C, Off, []),
            tokens(Text, Close + 1, Base, [{str, Off, S} | Acc]);
        C when (C >= $a andalso C =< $z); (C >= $A andalso C =< $Z); C =:= $_ ->
            {match, [N]} = re:run(Text, <<"\\G[A-Za-z_][A-Za-z0-9_]*">>,
                                  [{offset, I}, {capture, first, binary}]),
            tokens(Text, I + byte_size(N), Base, [{name, Off, N} | Acc]);
        _ ->
            Two = case I + 1 < byte_size(Text) of
                      true -> binary:part(Text, I, 2);
                      false -> <<>>
                  end,
            case lists:member(Two, [<<"==">>, <<"!=">>, <<"<=">>, <<">=">>, <<"//">>, <<"**">>]) of
                true ->
                    tokens(Text, I + 2, Base, [{op, Off, Two} | Acc]);
                false ->
                    One = binary:part(Text, I, 1),
                    case lists:member(One, [<<"+">>, <<"-">>, <<"*">>, <<"/">>, <<"%">>, <<"~">>,
                                            <<"<">>, <<">">>, <<"(">>, <<")">>, <<"[">>, <<"]">>,
                                            <<".">>, <<",">>, <<"|">>, <<"=">>, <<":">>,
                                            <<"{">>, <<"}">>]) of
                        true -> tokens(Text, I + 1, Base, [{op, Off, One} | Acc]);
                        false -> fail(["unexpected character '", printable(first_char(Text, I)),
                                       "' at offset ", integer_to_list(Off)])
                    end
            end
    end.

first_char(Text, I) ->
    Rest = binary:part(Text, I, byte_size(Text) - I),
    case string:next_codepoint(Rest) of
        [C | _] when is_integer(C) -> unicode:characters_to_binary([C]);
        _ -> binary:part(Rest, 0, 1)
    end.

string_literal(Text, I, _Quote, Off, _Acc) when I >= byte_size(Text) ->
    fail(["string at offset ", integer_to_list(Off), " is never closed"]);
string_literal(Text, I, Quote, Off, Acc) ->
    case binary:at(Text, I) of
        Quote ->
            {unicode:characters_to_binary(lists:reverse(Acc)), I};
        $\\ when I + 1 < byte_size(Text) ->
            C = case binary:at(Text, I + 1) of
                    $n -> $\n;
                    $t -> $\t;
                    X -> X
                end,
            string_literal(Text, I + 2, Quote, Off, [C | Acc]);
        C ->
            string_literal(Text, I + 1, Quote, Off, [C | Acc])
    end.

number(N) ->
    case binary:match(N, [<<".">>, <<"e">>, <<"E">>]) of
        nomatch ->
            I = binary_to_integer(N),
            I < ?MAX_INT orelse fail(["number ", printable(N), " is too large"]),
            I;
        _ ->
            F = try binary_to_float(N)
                catch error:badarg ->
                        %% "1e5" has no '.', which binary_to_float wants.
                        try binary_to_float(re:replace(N, <<"[eE]">>, <<".0e">>, [{return, binary}]))
                        catch error:badarg -> fail(["number ", printable(N), " is out of range"])
                        end
                end,
            F
    end.

%% ---------------------------------------------------------------------------
%% Expressions: grammar (lowest precedence first)
%% ---------------------------------------------------------------------------

parse_expr(_Ts, 0) ->
    fail("expression nested too deeply");
parse_expr(Ts, D) ->
    {Then, Ts1} = parse_or(Ts, D),
    case Ts1 of
        [{name, _, <<"if">>} | Ts2] ->
            {Cond, Ts3} = parse_or(Ts2, D - 1),
            case Ts3 of
                [{name, _, <<"else">>} | Ts4] ->
                    {Else, Ts5} = parse_expr(Ts4, D - 1),
                    {{ternary, Cond, Then, Else}, Ts5};
                _ ->
                    {{ternary, Cond, Then, {lit, undefined}}, Ts3}
            end;
        _ ->
            {Then, Ts1}
    end.

parse_or(Ts, D) ->
    {L, Ts1} = parse_and(Ts, D),
    binary_loop(Ts1, L, D, [<<"or">>], fun parse_and/2).

parse_and(Ts, D) ->
    {L, Ts1} = parse_not(Ts, D),
    binary_loop(Ts1, L, D, [<<"and">>], fun parse_not/2).

parse_not([{name, _, <<"not">>} | Ts], D) ->
    D > 1 orelse fail("expression nested too deeply"),
    {E, Ts1} = parse_not(Ts, D - 1),
    {{'not', E}, Ts1};
parse_not(Ts, D) ->
    parse_compare(Ts, D).

parse_compare(Ts, D) ->
    {L, Ts1} = parse_add(Ts, D),
    compare_loop(Ts1, L, D).

compare_loop([{op, _, Op} | Ts], L, D)
  when Op =:= <<"==">>; Op =:= <<"!=">>; Op =:= <<"<">>; Op =:= <<"<=">>; Op =:= <<">">>;
       Op =:= <<">=">> ->
    {R, Ts1} = parse_add(Ts, D),
    compare_loop(Ts1, {cmp, Op, L, R}, D);
compare_loop([{name, _, <<"in">>} | Ts], L, D) ->
    {R, Ts1} = parse_add(Ts, D),
    compare_loop(Ts1, {in, L, R}, D);
compare_loop([{name, _, <<"not">>}, {name, _, <<"in">>} | Ts], L, D) ->
    {R, Ts1} = parse_add(Ts, D),
    compare_loop(Ts1, {'not', {in, L, R}}, D);
compare_loop(Ts, L, _D) ->
    {L, Ts}.

parse_add(Ts, D) ->
    {L, Ts1} = parse_mul(Ts, D),
    binary_loop(Ts1, L, D, [<<"+">>, <<"-">>, <<"~">>], fun parse_mul/2).

parse_mul(Ts, D) ->
    {L, Ts1} = parse_unary(Ts, D),
    binary_loop(Ts1, L, D, [<<"*">>, <<"/">>, <<"//">>, <<"%">>], fun parse_unary/2).

%% Chains of operators are loops, not recursion: only nesting costs depth.
binary_loop([{Kind, _, Op} = T | Ts], L, D, Ops, Next) when Kind =:= op; Kind =:= name ->
    case lists:member(Op, Ops) of
        true ->
            {R, Ts1} = Next(Ts, D),
            binary_loop(Ts1, {arith, Op, L, R}, D, Ops, Next);
        false ->
            {L, [T | Ts]}
    end;
binary_loop(Ts, L, _D, _Ops, _Next) ->
    {L, Ts}.

parse_unary([{op, _, <<"-">>} | Ts], D) when D > 1 ->
    {E, Ts1} = parse_unary(Ts, D - 1),
    {{neg, E}, Ts1};
parse_unary([{op, _, <<"+">>} | Ts], D) when D > 1 ->
    parse_unary(Ts, D - 1);
parse_unary([{op, _, Op} | _], 1) when Op =:= <<"-">>; Op =:= <<"+">> ->
    fail("expression nested too deeply");
parse_unary(Ts, D) ->
    {P, Ts1} = parse_postfix(Ts, D),
    filter_loop(Ts1, P, D).

filter_loop([{op, _, <<"|">>}, {name, Off, Name} | Ts], E, D) ->
    {Args, Ts1} = case Ts of
                      [{op, _, <<"(">>} | Rest] -> call_args(Rest, D - 1);
                      _ -> {[], Ts}
                  end,
    check_filter(Name, length(Args), Off),
    filter_loop(Ts1, {filter, Name, E, Args}, D);
filter_loop([{op, _, <<"|">>}, T | _], _E, _D) ->
    unexpected(T);
filter_loop([{name, _, <<"is">>} | Ts], E, D) ->
    {Negate, Ts1} = case Ts of
                        [{name, _, <<"not">>} | R] -> {true, R};
                        _ -> {false, Ts}
                    end,
    case Ts1 of
        [{name, Off, Test} | Ts2] ->
            lists:member(Test, [<<"defined">>, <<"undefined">>, <<"none">>, <<"number">>,
                                <<"string">>])
                orelse fail(["unsupported test 'is ", printable(Test), "' at offset ",
                             integer_to_list(Off), " (supported: defined, undefined, none, "
                             "number, string)"]),
            Node = {test, Test, E},
            filter_loop(Ts2, case Negate of true -> {'not', Node}; false -> Node end, D);
        [T | _] ->
            unexpected(T)
    end;
filter_loop(Ts, E, _D) ->
    {E, Ts}.

-define(FILTERS, [{<<"float">>, 0, 1}, {<<"int">>, 0, 1}, {<<"round">>, 0, 2},
                  {<<"default">>, 0, 2}, {<<"d">>, 0, 2}, {<<"lower">>, 0, 0},
                  {<<"upper">>, 0, 0}, {<<"string">>, 0, 0}, {<<"abs">>, 0, 0},
                  {<<"trim">>, 0, 0}, {<<"length">>, 0, 0}, {<<"count">>, 0, 0},
                  {<<"multiply">>, 1, 1}, {<<"replace">>, 2, 2}, {<<"iif">>, 0, 3},
                  {<<"is_defined">>, 0, 0}, {<<"bool">>, 0, 1}]).

check_filter(Name, N, Off) ->
    case lists:keyfind(Name, 1, ?FILTERS) of
        {_, Min, Max} when N >= Min, N =< Max -> ok;
        {_, Min, Max} -> fail(["filter '", Name, "' at offset ", integer_to_list(Off), " takes ",
                               integer_to_list(Min), "..", integer_to_list(Max), " arguments"]);
        false -> fail(["unsupported filter '", printable(Name), "' at offset ", integer_to_list(Off),
                       " (supported: ", lists:join(", ", [F || {F, _, _} <- ?FILTERS]), ")"])
    end.

call_args([{op, _, <<")">>} | Ts], _D) ->
    {[], Ts};
call_args(Ts, D) ->
    call_args(Ts, D, []).

call_args(Ts, D, Acc) ->
    case Ts of
        [{name, Off, _}, {op, _, <<"=">>} | _] ->
            fail(["keyword arguments are not supported (offset ", integer_to_list(Off), ")"]);
        _ -> ok
    end,
    {A, Ts1} = parse_expr(Ts, D - 1),
    case Ts1 of
        [{op, _, <<",">>} | Ts2] -> call_args(Ts2, D, [A | Acc]);
        [{op, _, <<")">>} | Ts2] -> {lists:reverse([A | Acc]), Ts2};
        [T | _] -> unexpected(T)
    end.

parse_postfix(Ts, D) ->
    {P, Ts1} = parse_primary(Ts, D),
    postfix_loop(Ts1, P, D).

postfix_loop([{op, _, <<".">>}, {name, Off, Name} | Ts], E, D) ->
    case Ts of
        [{op, _, <<"(">>} | _] ->
            fail(["method calls such as '.", printable(Name), "()' are not supported (offset ",
                  integer_to_list(Off), ")"]);
        _ -> postfix_loop(Ts, {get, E, {lit, Name}}, D)
    end;
postfix_loop([{op, _, <<".">>}, {num, _, N} | Ts], E, D) when is_integer(N) ->
    postfix_loop(Ts, {get, E, {lit, N}}, D);
postfix_loop([{op, _, <<"[">>} | Ts], E, D) ->
    {K, Ts1} = parse_expr(Ts, D - 1),
    case Ts1 of
        [{op, _, <<"]">>} | Ts2] -> postfix_loop(Ts2, {get, E, K}, D);
        [{op, Off, <<":">>} | _] -> fail(["slices are not supported (offset ", integer_to_list(Off),
                                          ")"]);
        [T | _] -> unexpected(T)
    end;
postfix_loop([{op, _, <<".">>}, T | _], _E, _D) ->
    unexpected(T);
postfix_loop(Ts, E, _D) ->
    {E, Ts}.

-define(FUNCTIONS, [{<<"float">>, 1, 2}, {<<"int">>, 1, 2}, {<<"iif">>, 1, 4}, {<<"bool">>, 1, 2}]).

parse_primary([{num, _, N} | Ts], _D) -> {{lit, N}, Ts};
parse_primary([{str, _, S} | Ts], _D) -> {{lit, S}, Ts};
parse_primary([{name, _, N} | Ts], _D) when N =:= <<"true">>; N =:= <<"True">> -> {{lit, true}, Ts};
parse_primary([{name, _, N} | Ts], _D) when N =:= <<"false">>; N =:= <<"False">> -> {{lit, false}, Ts};
parse_primary([{name, _, N} | Ts], _D) when N =:= <<"none">>; N =:= <<"None">> -> {{lit, null}, Ts};
parse_primary([{name, Off, N}, {op, _, <<"(">>} | Ts], D) ->
    {Args, Ts1} = call_args(Ts, D - 1),
    case lists:keyfind(N, 1, ?FUNCTIONS) of
        {_, Min, Max} when length(Args) >= Min, length(Args) =< Max ->
            {{call, N, Args}, Ts1};
        {_, _, _} -> fail(["function '", N, "' at offset ", integer_to_list(Off),
                           " has the wrong number of arguments"]);
        false -> fail(["unsupported function '", printable(N), "()' at offset ",
                       integer_to_list(Off), " (supported: float, int, bool, iif)"])
    end;
parse_primary([{name, Off, N} | Ts], _D) ->
    case lists:member(N, [<<"if">>, <<"else">>, <<"and">>, <<"or">>, <<"not">>, <<"in">>,
                          <<"is">>]) of
        true -> unexpected({name, Off, N});
        false -> {{var, N}, Ts}
    end;
parse_primary([{op, _, <<"(">>} | Ts], D) ->
    {E, Ts1} = parse_expr(Ts, D - 1),
    case Ts1 of
        [{op, _, <<")">>} | Ts2] -> {E, Ts2};
        [T | _] -> unexpected(T)
    end;
parse_primary([{op, Off, <<"[">>} | _], _D) ->
    fail(["list literals are not supported (offset ", integer_to_list(Off), ")"]);
parse_primary([T | _], _D) ->
    unexpected(T).

-spec unexpected(tuple()) -> no_return().
unexpected({eof, Off}) ->
    fail(["the expression ends too early (offset ", integer_to_list(Off), ")"]);
unexpected({op, Off, <<"**">>}) ->
    fail(["unsupported operator '**' at offset ", integer_to_list(Off)]);
unexpected({_, Off, V}) ->
    fail(["unexpected '", printable(to_text(V)), "' at offset ", integer_to_list(Off)]).

%% ---------------------------------------------------------------------------
%% Evaluation
%% ---------------------------------------------------------------------------

run(Fun, Opts) ->
    put(mqtt_avatar_template_steps, maps:get(max_steps, Opts, ?MAX_STEPS)),
    try Fun() of
        Result ->
            Max = maps:get(max_output, Opts, ?MAX_OUTPUT),
            case is_binary(Result) andalso byte_size(Result) > Max of
                true -> {error, iolist_to_binary(io_lib:format("output longer than ~b bytes", [Max]))};
                false -> {ok, Result}
            end
    catch
        throw:{tpl_error, Message} -> {error, iolist_to_binary(Message)}
    after
        erase(mqtt_avatar_template_steps)
    end.

step() ->
    case get(mqtt_avatar_template_steps) of
        N when N > 0 -> put(mqtt_avatar_template_steps, N - 1);
        _ -> fail("evaluation takes too many steps")
    end.

render_nodes(Nodes, Vars) ->
    [render_node(N, Vars) || N <- Nodes].

render_node({text, T}, _Vars) ->
    T;
render_node({out, E}, Vars) ->
    to_text(eval(E, Vars));
render_node({'if', Branches, Else}, Vars) ->
    case [Body || {Cond, Body} <- Branches, truthy(eval(Cond, Vars))] of
        [Body | _] -> render_nodes(Body, Vars);
        [] -> render_nodes(Else, Vars)
    end.

eval(E, Vars) ->
    step(),
    eval1(E, Vars).

eval1({lit, V}, _Vars) -> V;
eval1({var, N}, Vars) -> maps:get(N, Vars, undefined);
eval1({get, E, K}, Vars) -> lookup(eval(E, Vars), eval(K, Vars));
eval1({ternary, C, T, F}, Vars) ->
    case truthy(eval(C, Vars)) of
        true -> eval(T, Vars);
        false -> eval(F, Vars)
    end;
eval1({'not', E}, Vars) -> not truthy(eval(E, Vars));
eval1({arith, <<"and">>, L, R}, Vars) ->
    V = eval(L, Vars),
    case truthy(V) of
        true -> eval(R, Vars);
        false -> V
    end;
eval1({arith, <<"or">>, L, R}, Vars) ->
    V = eval(L, Vars),
    case truthy(V) of
        true -> V;
        false -> eval(R, Vars)
    end;
eval1({arith, Op, L, R}, Vars) -> arith(Op, eval(L, Vars), eval(R, Vars));
eval1({neg, E}, Vars) -> arith(<<"-">>, 0, eval(E, Vars));
eval1({cmp, Op, L, R}, Vars) -> compare(Op, eval(L, Vars), eval(R, Vars));
eval1({in, L, R}, Vars) -> member(eval(L, Vars), eval(R, Vars));
eval1({test, T, E}, Vars) -> test(T, eval(E, Vars));
eval1({filter, Name, E, Args}, Vars) ->
    filter(Name, eval(E, Vars), [eval(A, Vars) || A <- Args]);
eval1({call, Name, [First | Args]}, Vars) ->
    filter(Name, eval(First, Vars), [eval(A, Vars) || A <- Args]).

lookup(M, K) when is_map(M), is_binary(K) -> maps:get(K, M, undefined);
lookup(L, K) when is_list(L), is_integer(K), K >= 0, K < length(L) -> lists:nth(K + 1, L);
lookup(L, K) when is_list(L), is_integer(K), K < 0, -K =< length(L) -> lists:nth(length(L) + K + 1, L);
lookup(B, K) when is_binary(B), is_integer(K) ->
    Chars = string:to_graphemes(B),
    N = length(Chars),
    I = case K < 0 of true -> N + K; false -> K end,
    case I >= 0 andalso I < N of
        true -> unicode:characters_to_binary([lists:nth(I + 1, Chars)]);
        false -> undefined
    end;
lookup(_, _) -> undefined.

truthy(undefined) -> false;
truthy(null) -> false;
truthy(false) -> false;
truthy(true) -> true;
truthy(0) -> false;
truthy(F) when is_float(F) -> F /= 0.0;
truthy(<<>>) -> false;
truthy([]) -> false;
truthy(M) when is_map(M) -> map_size(M) > 0;
truthy(_) -> true.

arith(<<"~">>, L, R) ->
    <<(to_text(L))/binary, (to_text(R))/binary>>;
arith(<<"+">>, L, R) when is_binary(L), is_binary(R) ->
    <<L/binary, R/binary>>;
arith(<<"+">>, L, R) when is_list(L), is_list(R) ->
    L ++ R;
arith(Op, L, R) ->
    A = num_operand(Op, L),
    B = num_operand(Op, R),
    checked(case Op of
                <<"+">> -> A + B;
                <<"-">> -> A - B;
                <<"*">> -> A * B;
                <<"/">> when B == 0 -> fail("division by zero");
                <<"/">> -> A / B;
                <<"//">> when B == 0 -> fail("division by zero");
                <<"//">> when is_integer(A), is_integer(B) -> floor_div(A, B);
                <<"//">> -> float(floor(A / B));
                <<"%">> when B == 0 -> fail("division by zero");
                <<"%">> when is_integer(A), is_integer(B) -> A - B * floor_div(A, B);
                <<"%">> -> A - B * floor(A / B)
            end).

floor_div(A, B) ->
    Q = A div B,
    case (A rem B =/= 0) andalso ((A < 0) xor (B < 0)) of
        true -> Q - 1;
        false -> Q
    end.

num_operand(_Op, true) -> 1;
num_operand(_Op, false) -> 0;
num_operand(_Op, N) when is_number(N) -> N;
num_operand(Op, undefined) -> fail(["an undefined value in '", Op, "' (use | default(...))"]);
num_operand(Op, V) -> fail(["'", Op, "' needs numbers, got ", describe(V), " (use | float or | int)"]).

checked(I) when is_integer(I), abs(I) < ?MAX_INT -> I;
checked(F) when is_float(F), abs(F) < ?MAX_FLOAT -> F;
checked(_) -> fail("number out of range").

compare(<<"==">>, L, R) -> equal(L, R);
compare(<<"!=">>, L, R) -> not equal(L, R);
compare(Op, L, R) ->
    {A, B} = case {L, R} of
                 _ when is_number(L), is_number(R) -> {L, R};
                 _ when is_binary(L), is_binary(R) -> {L, R};
                 _ when is_boolean(L), is_number(R) -> {num_operand(Op, L), R};
                 _ when is_number(L), is_boolean(R) -> {L, num_operand(Op, R)};
                 _ -> fail(["cannot compare ", describe(L), " and ", describe(R), " with '", Op, "'"])
             end,
    case Op of
        <<"<">> -> A < B;
        <<"<=">> -> A =< B;
        <<">">> -> A > B;
        <<">=">> -> A >= B
    end.

equal(A, B) when is_number(A), is_number(B) -> A == B;
equal(A, B) -> A =:= B.

member(K, M) when is_map(M) -> maps:is_key(K, M);
member(X, L) when is_list(L) -> lists:any(fun(Y) -> equal(X, Y) end, L);
member(X, B) when is_binary(X), is_binary(B) -> X =:= <<>> orelse binary:match(B, X) =/= nomatch;
member(X, B) -> fail(["cannot test ", describe(X), " in ", describe(B)]).

test(<<"defined">>, V) -> V =/= undefined;
test(<<"undefined">>, V) -> V =:= undefined;
test(<<"none">>, V) -> V =:= null;
test(<<"number">>, V) -> is_number(V);
test(<<"string">>, V) -> is_binary(V).

%% Filters and the functions of the same name.
filter(<<"float">>, V, Args) ->
    case to_number(V) of
        {ok, N} -> float(N);
        error -> case Args of
                     [D | _] -> D;
                     [] -> fail(["cannot convert ", describe(V), " to a number with float "
                                 "(give a default: float(0))"])
                 end
    end;
filter(<<"int">>, V, Args) ->
    case to_number(V) of
        {ok, N} when is_float(N) -> trunc(N);
        {ok, N} -> N;
        error -> case Args of
                     [D | _] -> D;
                     [] -> fail(["cannot convert ", describe(V), " to a number with int "
                                 "(give a default: int(0))"])
                 end
    end;
filter(<<"bool">>, V, Args) ->
    case V of
        _ when is_boolean(V) -> V;
        _ when is_number(V) -> V /= 0;
        _ when is_binary(V) ->
            case string:casefold(string:trim(V)) of
                T when T =:= <<"true">>; T =:= <<"yes">>; T =:= <<"on">>; T =:= <<"enable">>;
                       T =:= <<"1">> -> true;
                T when T =:= <<"false">>; T =:= <<"no">>; T =:= <<"off">>; T =:= <<"disable">>;
                       T =:= <<"0">>; T =:= <<"none">> -> false;
                _ -> bool_default(V, Args)
            end;
        _ -> bool_default(V, Args)
    end;
filter(<<"round">>, V, Args) ->
    N = case to_number(V) of
            {ok, X} -> X;
            error -> fail(["cannot round ", describe(V)])
        end,
    Digits = case Args of
                 [] -> 0;
                 [D | _] when is_integer(D), D >= 0, D =< 15 -> D;
                 [D | _] -> fail(["round needs 0..15 digits, got ", describe(D)])
             end,
    Method = case Args of
                 [_, M] -> M;
                 _ -> <<"common">>
             end,
    F = math:pow(10, Digits),
    R = case Method of
            <<"common">> -> round_half_away(N * F) / F;
            <<"floor">> -> floor(N * F) / F;
            <<"ceil">> -> ceil(N * F) / F;
            _ -> fail(["round method must be common, floor or ceil, got ", describe(Method)])
        end,
    checked(R);
filter(D, V, Args) when D =:= <<"default">>; D =:= <<"d">> ->
    Default = case Args of
                  [X | _] -> X;
                  [] -> <<>>
              end,
    Boolean = case Args of
                  [_, B] -> truthy(B);
                  _ -> false
              end,
    case V =:= undefined orelse (Boolean andalso not truthy(V)) of
        true -> Default;
        false -> V
    end;
filter(<<"lower">>, V, []) -> string:lowercase(to_text(V));
filter(<<"upper">>, V, []) -> string:uppercase(to_text(V));
filter(<<"string">>, V, []) -> to_text(V);
filter(<<"trim">>, V, []) -> string:trim(to_text(V));
filter(<<"abs">>, V, []) when is_number(V) -> abs(V);
filter(<<"abs">>, V, []) -> fail(["abs needs a number, got ", describe(V)]);
filter(L, V, []) when L =:= <<"length">>; L =:= <<"count">> ->
    if
        is_binary(V) -> string:length(V);
        is_list(V) -> length(V);
        is_map(V) -> map_size(V);
        true -> fail(["length of ", describe(V)])
    end;
filter(<<"multiply">>, V, [By]) ->
    case {to_number(V), By} of
        {{ok, N}, _} when is_number(By) -> checked(N * By);
        _ -> fail(["multiply needs numbers, got ", describe(V), " and ", describe(By)])
    end;
filter(<<"replace">>, V, [From, To]) when is_binary(From), From =/= <<>>, is_binary(To) ->
    binary:replace(to_text(V), From, To, [global]);
filter(<<"replace">>, _V, _) ->
    fail("replace needs two strings, the first not empty");
filter(<<"iif">>, V, Args) ->
    {T, F, N} = case Args of
                    [] -> {true, false, false};
                    [A] -> {A, false, false};
                    [A, B] -> {A, B, false};
                    [A, B, C] -> {A, B, C}
                end,
    case V of
        null when N =/= false -> N;
        _ -> case truthy(V) of
                 true -> T;
                 false -> F
             end
    end;
filter(<<"is_defined">>, undefined, []) ->
    fail("a value tested with is_defined is undefined");
filter(<<"is_defined">>, V, []) ->
    V.

bool_default(_V, [D | _]) -> D;
bool_default(V, []) -> fail(["cannot convert ", describe(V), " to a boolean"]).

round_half_away(X) when X >= 0 -> float(floor(X + 0.5));
round_half_away(X) -> -float(floor(-X + 0.5)).

to_number(N) when is_number(N) -> {ok, N};
to_number(true) -> {ok, 1};
to_number(false) -> {ok, 0};
to_number(B) when is_binary(B), byte_size(B) =< 64 ->
    T = string:trim(B),
    case re:run(T, <<"^[-+]?([0-9]+(\\.[0-9]*)?|\\.[0-9]+)([eE][-+]?[0-9]+)?$">>) of
        {match, _} ->
            Clean = case T of
                        <<"+", R/binary>> -> R;
                        _ -> T
                    end,
            try {ok, binary_to_integer(Clean)}
            catch error:badarg ->
                    case evatar_json:decode(normalise_float(Clean)) of
                        {ok, F} when is_number(F) -> {ok, float(F)};
                        _ -> error
                    end
            end;
        nomatch ->
            error
    end;
to_number(_) -> error.

%% JSON wants a digit on both sides of the point.
normalise_float(<<"-", R/binary>>) -> <<"-", (normalise_float(R))/binary>>;
normalise_float(<<".", R/binary>>) -> normalise_float(<<"0.", R/binary>>);
normalise_float(T) -> re:replace(T, <<"\\.([eE]|$)">>, <<".0\\1">>, [{return, binary}]).

describe(undefined) -> "an undefined value";
describe(null) -> "none";
describe(V) when is_boolean(V) -> ["the boolean ", to_text(V)];
describe(V) when is_number(V) -> ["the number ", to_text(V)];
describe(V) when is_binary(V) -> ["the string '", printable(V), "'"];
describe(V) when is_list(V) -> "a list";
describe(V) when is_map(V) -> "an object".

%% ---------------------------------------------------------------------------
%% Plain paths
%% ---------------------------------------------------------------------------

expr_path({filter, F, E, _}) ->
    case lists:member(F, [<<"float">>, <<"int">>, <<"string">>, <<"round">>, <<"trim">>]) of
        true -> expr_path(E);
        false -> error
    end;
expr_path({var, <<"value">>}) -> {ok, raw};
expr_path({var, <<"value_json">>}) -> {ok, {json, []}};
expr_path({get, E, {lit, K}}) ->
    Seg = case K of
              B when is_binary(B), B =/= <<>> -> {ok, B};
              I when is_integer(I), I >= 0 -> {ok, integer_to_binary(I)};
              _ -> error
          end,
    case {expr_path(E), Seg} of
        {{ok, {json, P}}, {ok, S}} -> {ok, {json, P ++ [S]}};
        _ -> error
    end;
expr_path(_) -> error.

%% ---------------------------------------------------------------------------
%% Helpers
%% ---------------------------------------------------------------------------

-spec fail(iodata()) -> no_return().
fail(Message) ->
    throw({tpl_error, Message}).

printable(B) when is_binary(B) ->
    case byte_size(B) > 40 of
        true -> <<(binary:part(B, 0, 40))/binary, "...">>;
        false -> B
    end.
